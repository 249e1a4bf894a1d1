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
The demo's own node (Driver) and the run of the demo over DDS (drive()).

drive() starts valve_node and analyser_node as processes (in ROS_DOMAIN_ID if set,
otherwise in a domain no other run on this machine holds), and the Driver commands
5 L/min until the analyser records every topic, holds it until valve_node's model
time has advanced HOLD_TIME in step with the wall clock, steps to 20 L/min and waits
for the analyser's live measures of the step; a step whose samples are too sparse
for its measures (analysis.recorded_steps.sampling_problem) is stepped back and tried
again, up to ATTEMPTS times. Then both nodes stop with SIGINT. `valve-sim demo`
(valve_sim.commands.demo) reports the bag.
"""

from pathlib import Path
import re
import time

import numpy as np
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP
from valve_sim.analysis.recorded_steps import sampling_problem
from valve_sim.analysis.steps.measures import WINDOW
from valve_sim.core.errors import IncompleteRunError, WaitTimeoutError


INITIAL_FLOW = REFERENCE_FLOW_STEP.initial_flow  # [m^3/s] 5 L/min
FINAL_FLOW = REFERENCE_FLOW_STEP.final_flow  # [m^3/s] 20 L/min
HOLD_TIME = 1.0  # [s] at the initial flow, once everything is recorded
# Share of the wall-clock time the valve's model time must advance over the hold: a node
# still compiling, or skipping lag, advances far less; a loaded but working one about 1.
REAL_TIME_SHARE = 0.8
AFTER_MEASURES = 0.2  # [s] still recorded after the measures arrived
COMMAND_PERIOD = 0.02  # [s] inlet_flow is published at 50 Hz (valve_node's input timeout is 1 s)
READY_TIMEOUT = 180.0  # [s] for start-up (a cold kernel compile on a loaded machine) and discovery
MEASURES_TIMEOUT = 60.0  # [s] from the step to the analyser's measures
ATTEMPTS = 20  # steps tried (some 5 s each) before the demo gives up: load often passes


def progress(text):
    print(f'demo: {text}', flush=True)


class Driver:
    """The demo's own node: commands the inlet flow, follows the valve and the analyser."""

    def __init__(self, processes, folder, live_view=False):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.node import Node
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64
        from valve_sim.ros.analyser_node import NODE_NAME, RECORDING_TASK
        from valve_sim.ros.measures_publisher import MEASURES_QOS
        from valve_sim.ros.spinning import DEFAULT_EXECUTOR, EXECUTORS

        self.processes, self.folder, self.flow = processes, folder, INITIAL_FLOW
        self.live_view = live_view  # valve_node serves one: say where, once it runs
        self.node = Node('valve_demo')
        # valve_node's executor: rclpy's default one falls behind 1 kHz on a busy machine
        self.executor = EXECUTORS[DEFAULT_EXECUTOR]()
        self.executor.add_node(self.node)
        self.bag = None  # the analyser's file, once it records every topic
        self.measures = []  # step_measures messages
        self.model_time_ns = None  # stamp of the valve's latest state
        self.stamps = []  # [s] model times of the valve's states received
        self.valve_ready = False  # valve_node's /diagnostics said so
        self.attempts = 0  # steps up commanded
        publisher = self.node.create_publisher(Float64, 'inlet_flow', 10)
        self.node.create_timer(COMMAND_PERIOD, lambda: publisher.publish(Float64(data=self.flow)))

        def on_status(array):
            recording = f'{NODE_NAME}: {RECORDING_TASK}'  # the analyser keeps its name
            for status in array.status:
                values = {pair.key: pair.value for pair in status.values}
                if status.name == recording and all(
                    int(count) > 0 for key, count in values.items() if key.startswith('messages /')
                ):
                    self.bag = Path(values['file'])
                if 'startup_kernels_s' in values and not self.valve_ready:
                    self.valve_ready = True  # valve_node reports only once it ticks
                    seconds = float(values['startup_kernels_s'])
                    progress(f'valve_node ready: kernels compiled or loaded in {seconds:.1f} s')

        def on_state(message):
            self.model_time_ns = message.header.stamp.sec * 10**9 + message.header.stamp.nanosec
            self.stamps.append(self.model_time_ns / 1e9)

        self.node.create_subscription(DiagnosticArray, '/diagnostics', on_status, 10)
        self.node.create_subscription(JointState, 'applied_inlet_flow', on_state, 1000)
        self.node.create_subscription(
            DiagnosticArray, 'step_measures', self.measures.append, MEASURES_QOS
        )

    def spin_until(self, condition, timeout, what):
        """Spin until condition() holds; raises TimeoutError or ChildProcessError (a node died)."""
        from valve_sim.ros.node_processes import spin_until

        spin_until(self.executor, condition, timeout, what, self.processes)

    def run_step(self):
        """
        Wait for the recording and a valve in real time; hold, step, wait for the measures.

        A step whose received states are too sparse for its measures (sampling_problem)
        is stepped back down and tried again, up to ATTEMPTS steps; raises
        IncompleteRunError after that. Returns the bag path (attempts: the steps up).
        """
        progress(
            'waiting for the nodes to start and discover each other; valve_node compiles '
            'its model kernels first (tens of seconds on the first run, then cached) '
            f'(commanding {self.flow * 6e4:g} L/min)'
        )
        self.spin_until(
            lambda: self.bag is not None and self.model_time_ns is not None,
            READY_TIMEOUT,
            'recording of every topic by the analyser',
        )
        progress(f'analyser records every topic to {self.bag}')
        if self.live_view:
            self._announce_live_view()
        for self.attempts in range(1, ATTEMPTS + 1):
            self._hold_in_real_time()
            self.flow = FINAL_FLOW
            progress(
                f'inlet flow stepped to {self.flow * 6e4:g} L/min; '
                "waiting for the analyser's measures (1 s of model time after the step)"
            )
            t_step, values = self._measured_step()
            self._receive_states_until(t_step + WINDOW)
            problem = sampling_problem(np.array(self.stamps), t_step, values)
            if problem is None:
                break
            progress(
                f'step {self.attempts} of at most {ATTEMPTS} cannot be measured: {problem} '
                f'(valve_node fell behind real time); stepping back to {INITIAL_FLOW * 6e4:g} '
                'L/min to try again'
            )
            self.flow = INITIAL_FLOW
            self._measured_step()
        else:
            raise IncompleteRunError(
                f'no step could be measured in {ATTEMPTS} attempts, the last had {problem}: '
                'valve_node cannot keep real time on this machine now (too busy?) '
                f'(logs in {self.folder})'
            )
        self._spin_for(AFTER_MEASURES)
        return self.bag

    def _measured_step(self):
        """Wait for the analyser's measures of the step just commanded: (t_step [s], values)."""
        from valve_sim.ros.measures_publisher import measures_from_message

        count = len(self.measures)
        self.spin_until(
            lambda: len(self.measures) > count, MEASURES_TIMEOUT, 'step measures from the analyser'
        )
        message = self.measures[count]
        values = {pair.key: pair.value for pair in message.status[0].values}
        return float(values['t_step_s']), measures_from_message(message)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()

    def _receive_states_until(self, end):
        """
        Spin until this node has the valve's states up to model time end [s].

        The analyser can measure a step before they all reach this node (under
        load), and the sampling check must see the whole window: a gap it cannot
        see would refuse the report of the bag afterwards.
        """
        self.spin_until(
            lambda: self.model_time_ns >= end * 1e9,
            MEASURES_TIMEOUT,
            "the valve's states through the step's window",
        )

    def _announce_live_view(self):
        """Print the address valve_node logged for its Foxglove server, and the layout."""
        from valve_sim.ros.live_view import layout_path

        log = self.folder / 'valve_node.log'
        found = re.search(r'Foxglove live view on ws://[\w.]+:(\d+)', log.read_text())
        address = f'ws://localhost:{found[1]}' if found else f'nowhere (see {log})'
        progress(f'Foxglove live view: {address}; layout {layout_path()}')

    def _hold_in_real_time(self):
        """
        Hold the initial flow until the valve's model time keeps pace with the wall clock.

        Raises TimeoutError if it never does within READY_TIMEOUT.
        """
        deadline = time.monotonic() + READY_TIMEOUT
        while True:
            progress(f'holding {self.flow * 6e4:g} L/min for {HOLD_TIME:g} s')
            wall, model = time.monotonic(), self.model_time_ns
            self._spin_for(HOLD_TIME)
            share = (self.model_time_ns - model) / 1e9 / (time.monotonic() - wall)
            if share >= REAL_TIME_SHARE:
                progress(f'valve_node advances in real time ({share:.2f} s of model time per s)')
                return
            if time.monotonic() > deadline:
                raise WaitTimeoutError(
                    f'valve_node advanced only {share:.2f} s of model time per second of wall '
                    f'time after {READY_TIMEOUT:g} s (needs {REAL_TIME_SHARE:g}; the machine is '
                    f'too busy for real time?) (log: {self.folder / "valve_node.log"})'
                )
            progress(f'valve_node advanced {share:.2f} s of model time per s: not yet real time')

    def _spin_for(self, duration):
        end = time.monotonic() + duration
        self.spin_until(lambda: time.monotonic() >= end, duration + 10.0, 'the end of a hold')


def drive(folder, foxglove=None):
    """
    Run the demo's step on both nodes, their logs into folder; return (bag, attempts).

    foxglove: the port of valve_node's live view (None: none). attempts: the steps up
    commanded (Driver.run_step). Raises what Driver.run_step raises; stops both nodes.
    """
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from valve_sim.ros.isolation import claim_domain
    from valve_sim.ros.node_processes import start_valve_and_analyser

    progress(f'output folder {folder}; ROS_DOMAIN_ID={claim_domain()}')
    progress('starting valve_node and analyser_node')
    processes = start_valve_and_analyser(
        folder, [] if foxglove is None else ['--foxglove', str(foxglove)]
    )
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    driver = None
    try:
        driver = Driver(processes, folder, foxglove is not None)
        bag = driver.run_step()
    finally:
        if driver is not None:
            driver.close()
        rclpy.try_shutdown()
        progress('stopping both nodes (SIGINT)')
        processes.stop()
    progress('both nodes stopped cleanly')
    return bag, driver.attempts
