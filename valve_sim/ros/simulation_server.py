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
valve_simulator: valve_sim as the bench's simulator, stepped through simulation_interfaces.

    valve_simulator SCENARIO.yaml [--output-dir DIR]

It owns /clock: it starts valve_node as the scenario runner does (on use_sim_time with
stamped lockstep inputs and the scenario's parameters: scenario_runner.valve_arguments)
and drives it in lockstep (ros.lockstep) through the runner's ScenarioStepper
(ros.scenario_stepper), so the states are the scenario runner's, byte for byte. A
client in any language steps it through the standard services of simulation_interfaces
(docs/scenarios.md), all under the node valve_simulator:
  ~/get_simulator_features  GetSimulatorFeatures  the features below
  ~/get_simulation_state    GetSimulationState    STOPPED, PLAYING, PAUSED
  ~/set_simulation_state    SetSimulationState    play (real time), pause, stop (= reset), quit
  ~/step_simulation         StepSimulation        steps ticks while paused
  ~/simulate_steps          SimulateSteps action  the same, with feedback after each tick
  ~/reset_simulation        ResetSimulation       valve_node's ~/restart, /clock at the start
A step is one tick of valve_node (1 / publish_rate of model time). A reset is
SCOPE_ALL whatever the scope asked: time, state and parameters back to the start, as if
closed and launched again (valve_node's ~/restart, in the same process: milliseconds
instead of a process's start; a valve_node that ended is started again).
"""

import argparse
from pathlib import Path
import sys
import tempfile
import time

import rclpy
from rclpy.action import ActionServer
try:
    from simulation_interfaces.action import SimulateSteps
    from simulation_interfaces.msg import Result, SimulationState, SimulatorFeatures
    from simulation_interfaces.srv import (
        GetSimulationState,
        GetSimulatorFeatures,
        ResetSimulation,
        SetSimulationState,
        StepSimulation,
    )
except ImportError as error:
    from valve_sim.core.errors import MissingExtraError  # a ValveSimError and an ImportError

    raise MissingExtraError(
        f'{error}: valve_simulator needs simulation_interfaces: `python3 run.py install` builds '
        'it into .venv (interfaces/README.md); on a ROS install: ros-jazzy-simulation-interfaces'
    ) from None
from valve_sim.core.errors import IncompleteRunError, ParameterError
from valve_sim.ros import node_command, spinning
from valve_sim.ros.lockstep import Lockstep, NS_PER_S
from valve_sim.ros.lockstep_protocol import LateInputError
from valve_sim.ros.node_processes import NodeProcesses
from valve_sim.ros.scenario_runner import READY_TIMEOUT, valve_arguments
from valve_sim.ros.scenario_stepper import ScenarioStepper


NODE_NAME = 'valve_simulator'
FEATURES = [
    SimulatorFeatures.SIMULATION_RESET,
    SimulatorFeatures.SIMULATION_STATE_GETTING,
    SimulatorFeatures.SIMULATION_STATE_SETTING,
    SimulatorFeatures.SIMULATION_STATE_PAUSE,
    SimulatorFeatures.STEP_SIMULATION_SINGLE,
    SimulatorFeatures.STEP_SIMULATION_MULTIPLE,
    SimulatorFeatures.STEP_SIMULATION_ACTION,
]
PLAY_PERIOD = 0.01  # [s] of wall time between the playing simulator's catch-ups
MAX_PLAY_TICKS = 100  # ticks one catch-up runs at most: services still answer meanwhile
STEP_ERRORS = (IncompleteRunError, LateInputError, TimeoutError, ChildProcessError)
RESTART_ERRORS = STEP_ERRORS + (ParameterError,)


class SimulationServer:
    """The simulation-control services around a valve_node stepped through a scenario."""

    def __init__(self, context, scenario, folder):
        self.context, self.scenario, self.folder = context, scenario, folder
        self.node = rclpy.create_node(NODE_NAME, context=context)
        self.state = SimulationState.STATE_STOPPED
        self.quit = False
        self.processes = self.driver = self.stepper = None
        self._played_from = None  # (wall time, tick) playing started from
        node = self.node
        node.create_service(GetSimulatorFeatures, '~/get_simulator_features',
                            self._on_features)
        node.create_service(GetSimulationState, '~/get_simulation_state', self._on_get_state)
        node.create_service(SetSimulationState, '~/set_simulation_state', self._on_set_state)
        node.create_service(StepSimulation, '~/step_simulation', self._on_step)
        node.create_service(ResetSimulation, '~/reset_simulation', self._on_reset)
        self.action = ActionServer(node, SimulateSteps, '~/simulate_steps', self._on_steps)
        self.play_timer = node.create_timer(PLAY_PERIOD, self._play)
        self.play_timer.cancel()
        self.start()

    # --- the valve ------------------------------------------------------------------------

    def start(self):
        """Start valve_node for the scenario and its first state at the start time."""
        scenario = self.scenario
        self.processes = NodeProcesses(self.folder, {
            'valve_node': node_command('valve_node', (), *valve_arguments(scenario))})
        try:
            self.driver = Lockstep(self.context, processes=self.processes,
                                   tank='tank_pressure' in scenario.inputs)
            self.driver.connect((), READY_TIMEOUT)
            self._first_state()
        except STEP_ERRORS:
            self.stop_valve()  # no valve_node left running behind
            raise

    def _first_state(self):
        """Step the connected driver's valve to its first state (the scenario's start)."""
        self.stepper = ScenarioStepper(self.scenario, self.driver)
        self.stepper.start()
        self.node.get_logger().info(
            f'valve_node at {self.stepper.time_ns / NS_PER_S:g} s, stopped; scenario '
            f'{self.scenario.name}, steps of {self.scenario.period_ns / NS_PER_S:g} s')

    def stop_valve(self):
        """Stop valve_node (SIGINT) and the driver."""
        if self.driver is not None:
            self.driver.close()
        if self.processes is not None:
            self.processes.stop()
        self.processes = self.driver = self.stepper = None

    def reset(self):
        """
        Back to the start, stopped: valve_node's ~/restart, in the same process.

        Its start-up parameters are the scenario's, so the restart gives the state of a
        new valve_node (ros.valve_restart). A valve_node that does not restart (it
        ended, or the last reset failed) is started again.
        """
        self.play_timer.cancel()
        restarted = False
        if self.stepper is not None:
            self.stepper = None
            try:
                self.driver.restart(timeout=READY_TIMEOUT)
                self._first_state()
                restarted = True
            except RESTART_ERRORS as error:
                self.node.get_logger().warn(f'valve_node did not restart ({error}): starting '
                                            'a new one')
        if not restarted:
            self.stop_valve()
            self.start()
        self.state = SimulationState.STATE_STOPPED

    def step(self, count):
        """Step count ticks; return an error message, or None."""
        if self.stepper is None:
            return 'no valve_node: the last reset failed (see the log); reset again'
        try:
            self.stepper.step(count)
        except STEP_ERRORS as error:
            return f'stepping failed after tick {self.stepper.tick}: {error}'
        return None

    # --- services -------------------------------------------------------------------------

    def _on_features(self, request, response):
        response.features.features = FEATURES
        response.features.custom_info = (
            'valve_sim: a step is one tick of valve_node; docs/scenarios.md')
        return response

    def _on_get_state(self, request, response):
        response.state.state = self.state
        response.result.result = Result.RESULT_OK
        return response

    def _on_set_state(self, request, response):
        target = request.state.state
        result = response.result
        result.result = Result.RESULT_OK
        if target == self.state:
            result.result = SetSimulationState.Response.ALREADY_IN_TARGET_STATE
        elif self.stepper is None and target in (SimulationState.STATE_PLAYING,
                                                 SimulationState.STATE_PAUSED):
            result.result = SetSimulationState.Response.STATE_TRANSITION_ERROR
            result.error_message = 'no valve_node: the last reset failed; reset again'
        elif target == SimulationState.STATE_PLAYING:
            self._played_from = (time.monotonic(), self.stepper.tick)
            self.play_timer.reset()
            self.state = target
        elif target == SimulationState.STATE_PAUSED:
            self.play_timer.cancel()
            self.state = target
        elif target == SimulationState.STATE_STOPPED:
            try:
                self.reset()
            except STEP_ERRORS as error:
                result.result = SetSimulationState.Response.STATE_TRANSITION_ERROR
                result.error_message = f'reset failed: {error}'
        elif target == SimulationState.STATE_QUITTING:
            self.play_timer.cancel()
            self.state, self.quit = target, True
        else:
            result.result = SetSimulationState.Response.INCORRECT_TRANSITION
            result.error_message = f'state {target} cannot be set (no worlds here)'
        return response

    def _on_step(self, request, response):
        response.result = self._check_paused(request.steps)
        if response.result.result == Result.RESULT_OK:
            error = self.step(request.steps)
            if error is not None:
                response.result = failed(error)
        return response

    def _on_reset(self, request, response):
        try:
            self.reset()
        except STEP_ERRORS as error:
            response.result = failed(f'reset failed: {error}')
            return response
        response.result.result = Result.RESULT_OK
        return response

    def _on_steps(self, goal_handle):
        steps = goal_handle.request.steps
        outcome = SimulateSteps.Result(result=self._check_paused(steps))
        if outcome.result.result != Result.RESULT_OK:
            goal_handle.abort()
            return outcome
        for done in range(1, steps + 1):
            error = self.step(1)
            if error is not None:
                outcome.result = failed(error)
                goal_handle.abort()
                return outcome
            goal_handle.publish_feedback(SimulateSteps.Feedback(
                completed_steps=done, remaining_steps=steps - done))
        goal_handle.succeed()
        return outcome

    def _check_paused(self, steps):
        """Return the Result of a step request: OK only while paused, for 1 step or more."""
        if self.state != SimulationState.STATE_PAUSED:
            return failed('the simulation steps only while paused')
        if steps < 1:
            return failed(f'steps = {steps}: at least 1')
        return Result(result=Result.RESULT_OK)

    def _play(self):
        """Playing: step up to real time (at most MAX_PLAY_TICKS at once)."""
        wall, tick = self._played_from
        if self.stepper is None:
            return
        due = tick + int((time.monotonic() - wall) * NS_PER_S / self.scenario.period_ns)
        count = min(due - self.stepper.tick, MAX_PLAY_TICKS)
        if count > 0:
            error = self.step(count)
            if error is not None:
                self.node.get_logger().error(f'{error}; paused')
                self.play_timer.cancel()
                self.state = SimulationState.STATE_PAUSED

    def close(self):
        self.play_timer.cancel()
        self.action.destroy()
        self.stop_valve()
        self.node.destroy_node()


def failed(message):
    """Return an OPERATION_FAILED Result with message."""
    return Result(result=Result.RESULT_OPERATION_FAILED, error_message=message)


def main(args=None):
    """Run valve_simulator until SIGINT, SIGTERM or STATE_QUITTING; returns the exit code."""
    from rclpy.utilities import remove_ros_args
    from valve_sim.analysis.scenarios.bench_scenario import load_scenario
    from valve_sim.core.errors import USER_ERRORS

    parser = argparse.ArgumentParser(prog='valve_simulator', description=__doc__.split('\n')[1])
    parser.add_argument('scenario', type=Path, help='the scenario file: parameters, inputs, '
                        'events (docs/scenarios.md); its expectations are not judged')
    parser.add_argument('--output-dir', type=Path, default=None,
                        help="folder of valve_node's log (default: a temporary folder)")
    options = parser.parse_args(remove_ros_args(sys.argv if args is None else args)[1:])
    try:
        scenario = load_scenario(options.scenario)
    except USER_ERRORS as error:
        print(f'valve_simulator: {error}', file=sys.stderr)
        return 1
    stop = spinning.init(args)
    with tempfile.TemporaryDirectory(prefix='valve_simulator_') as temporary:
        folder = options.output_dir or Path(temporary)
        folder.mkdir(parents=True, exist_ok=True)
        try:
            server = SimulationServer(rclpy.get_default_context(), scenario, folder)
        except STEP_ERRORS as error:
            print(f'valve_simulator: valve_node did not start: {error}', file=sys.stderr)
            rclpy.try_shutdown()
            return 1
        executor = spinning.EXECUTORS['single-threaded']()
        executor.add_node(server.node)
        try:
            while not stop.is_set() and not server.quit:
                executor.spin_once(timeout_sec=spinning.SPIN_TIMEOUT)
        finally:
            executor.shutdown()
            server.close()
            rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
