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
The paper's step over real DDS: valve_node and analyser_node, 5 -> 20 L/min, recorded and measured.

Starts both nodes as processes (in ROS_DOMAIN_ID if set, otherwise in a domain no other
run on this machine holds, discovery kept on this machine), commands 5 L/min until the
analyser records every topic, holds it until valve_node's model time has advanced
HOLD_TIME in step with the wall clock (it compiles its kernels before it ticks, which
takes tens of seconds on a fresh clone), steps to 20 L/min, waits for the analyser's live
measures of the step, and stops both nodes with SIGINT. A step whose samples are too
sparse for its measures (valve_node fell behind real time on a busy machine) is stepped
back and tried again, up to ATTEMPTS times. Then it prints the six measures beside the
paper's, checks them against an offline analysis of the bag, and draws Figure 5. The
folder gets the bag, its measures JSON, figure5.png and the two nodes' logs. Exits 1 with
one line saying what is missing if any measure, the bag or the figure is.
"""

import math
from pathlib import Path
import re
import time

import numpy as np
from valve_sim.analysis.measures import MEASURE_NAMES, WINDOW
from valve_sim.analysis.paper import REFERENCE_SCENARIO
from valve_sim.commands.cli import make_folder
from valve_sim.commands.options import add_options
from valve_sim.core.errors import IncompleteRunError
from valve_sim.core.input_files import MEASURES_FILE, read_json


# Live and offline measures come from the same code on the same samples; they may differ
# in the last bits when the analyser ran on another machine or NumPy build.
SAME_MEASURE_TOLERANCE = 1e-9  # relative
INITIAL_FLOW = REFERENCE_SCENARIO.initial_flow  # [m^3/s] 5 L/min
FINAL_FLOW = REFERENCE_SCENARIO.final_flow  # [m^3/s] 20 L/min
HOLD_TIME = 1.0  # [s] at the initial flow, once everything is recorded
# Share of the wall-clock time the valve's model time must advance over the hold: a node
# still compiling, or skipping lag, advances far less; a loaded but working one about 1.
REAL_TIME_SHARE = 0.8
AFTER_MEASURES = 0.2  # [s] still recorded after the measures arrived
COMMAND_PERIOD = 0.02  # [s] inlet_flow is published at 50 Hz (valve_node's input timeout is 1 s)
READY_TIMEOUT = 180.0  # [s] for start-up (a cold kernel compile on a loaded machine) and discovery
MEASURES_TIMEOUT = 60.0  # [s] from the step to the analyser's measures
# [s] Sampling the measures need (docs/analyser.md, "The demo"). Each peak is refined by
# a parabola through the samples near it, so close to a peak (within T_d / 8) states may
# be at most PEAK_GAP_LIMIT apart, elsewhere in the window WINDOW_GAP_LIMIT (longer is
# also lag valve_node may have skipped: model time jumped, the state held). Offline at
# 1 kHz a 4 ms interval next to the first peak moves T_1 by 12 %; 3 ms intervals, and 10 ms
# ones away from the peaks, move no measure by more than a tenth of its test tolerance.
PEAK_GAP_LIMIT = 0.003
WINDOW_GAP_LIMIT = 0.01
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
        from valve_sim.ros.analyser_node import MEASURES_QOS, NODE_NAME, RECORDING_TASK
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
        from valve_sim.ros.analyser_node import measures_from_message

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
                raise TimeoutError(
                    f'valve_node advanced only {share:.2f} s of model time per second of wall '
                    f'time after {READY_TIMEOUT:g} s (needs {REAL_TIME_SHARE:g}; the machine is '
                    f'too busy for real time?) (log: {self.folder / "valve_node.log"})'
                )
            progress(f'valve_node advanced {share:.2f} s of model time per s: not yet real time')

    def _spin_for(self, duration):
        end = time.monotonic() + duration
        self.spin_until(lambda: time.monotonic() >= end, duration + 10.0, 'the end of a hold')


def sampling_problem(times, t_step, values):
    """
    Say why samples at times [s] cannot carry the measures of the step at t_step [s], or None.

    values: the step's measures, whose T_1 and T_d place its peaks (where those are
    undefined, every sample counts as next to a peak).
    """
    shown = times[(times >= t_step) & (times <= t_step + WINDOW)]
    if shown.size < 2:
        return 'no samples in its window'
    t_1, t_d = values.get('T_1_ms'), values.get('T_d_ms')
    if t_1 is None or t_d is None:
        peaks, near = np.array([t_step]), WINDOW
    else:
        peaks, near = t_step + np.array([t_1, t_1 + t_d]) * 1e-3, t_d * 1e-3 / 8
    for start, end in zip(shown[:-1], shown[1:]):
        at_peak = np.any((start < peaks + near) & (end > peaks - near))
        limit = PEAK_GAP_LIMIT if at_peak else WINDOW_GAP_LIMIT
        if end - start > limit:
            return (
                f'a gap of {(end - start) * 1e3:.1f} ms between samples '
                f'{"next to a peak" if at_peak else "in its window"}, '
                f'{(start - t_step) * 1e3:.0f} ms after the step '
                f'(at most {limit * 1e3:g} ms there)'
            )
    return None


def measures_agree(first, second):
    """Return True if two steps' measures agree to SAME_MEASURE_TOLERANCE (undefined alike)."""
    for name in MEASURE_NAMES:
        a, b = first[name], second[name]
        if a is None or b is None:
            if a is not b:
                return False
        elif not math.isclose(a, b, rel_tol=SAME_MEASURE_TOLERANCE):
            return False
    return True


def report(folder, bag, attempts=1):
    """
    Print the live measures beside the paper's and the offline check; draw Figure 5.

    attempts: steps up commanded; each but the last was stepped back down, so the bag
    holds 2 attempts - 1 steps and the last is the one shown. Returns the JSON path.
    Raises IncompleteRunError, naming what is missing, if a measure is undefined, the
    recorded samples cannot carry them, the offline analysis disagrees (beyond
    SAME_MEASURE_TOLERANCE), or the figure was not written.
    """
    from valve_sim.commands.analyse import analyse, plot_steps, print_steps, read_recording

    measures_path = bag.with_suffix('.measures.json')
    live = read_json(measures_path, MEASURES_FILE)['steps']
    recording = read_recording(bag)
    if len(live) != 2 * attempts - 1 or live[-1]['direction'] != 1:
        raise IncompleteRunError(
            f'the analyser measured {len(live)} steps instead of the {2 * attempts - 1} '
            f'commanded (bag {bag}, measures {measures_path})'
        )
    offline = analyse(recording)
    step = live[-1]
    print()
    if attempts > 1:
        print(
            f'the step up of attempt {attempts}: the {attempts - 1} before it could not be '
            'measured; they and their steps back down are in the bag too'
        )
    print_steps([step], recording, first_number=len(live), paper=True)  # the reference valve
    same = len(offline) == len(live) and all(map(measures_agree, offline, live))
    print(
        '\noffline analysis of the bag: '
        f'{"the same measures" if same else "DIFFERENT measures: " + str(offline)}'
    )
    figure = plot_steps(folder / 'figure5.png', recording, [step], first_number=len(live))[0]
    for path in (bag, measures_path, figure):
        progress(f'wrote {path}')
    undefined = {
        name: step['reasons'].get(name, 'no value')
        for name in MEASURE_NAMES
        if step[name] is None or not math.isfinite(step[name])
    }
    if undefined:
        raise IncompleteRunError(
            'measure(s) undefined: '
            + '; '.join(f'{name}: {reason}' for name, reason in undefined.items())
            + f' (logs in {folder})'
        )
    if not same:
        raise IncompleteRunError(f'the offline analysis of {bag} gives different measures')
    problem = sampling_problem(recording.time, step['t_step'], step)
    if problem:
        raise IncompleteRunError(f'the recorded step in {bag} cannot be measured: {problem}')
    if not figure.is_file() or figure.stat().st_size == 0:
        raise IncompleteRunError(f'{figure} was not written')
    return measures_path


def add_arguments(parser):
    from valve_sim.ros.live_view import add_port_option, DEFAULT_PORT, layout_path

    add_options(parser, '--out', required=False,
                help='folder for the bag, measures JSON, figure and logs (default: a new '
                'demo_<date>-<time> folder in the current directory)')
    add_port_option(parser, 'valve_node serves a live view over the Foxglove WebSocket protocol '
                    f'on this port of this machine (default {DEFAULT_PORT}; 0: any free port): '
                    f'open it in the Foxglove app with the layout {layout_path()}')


def run(args):
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from valve_sim.ros.isolation import claim_domain
    from valve_sim.ros.node_processes import start_valve_and_analyser

    folder = Path(args.out) if args.out else Path.cwd() / time.strftime('demo_%Y%m%d-%H%M%S')
    folder = make_folder(folder).resolve()
    progress(f'output folder {folder}; ROS_DOMAIN_ID={claim_domain()}')
    progress('starting valve_node and analyser_node')
    processes = start_valve_and_analyser(
        folder, [] if args.foxglove is None else ['--foxglove', str(args.foxglove)]
    )
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    driver = None
    try:
        driver = Driver(processes, folder, args.foxglove is not None)
        bag = driver.run_step()
    finally:
        if driver is not None:
            driver.close()
        rclpy.try_shutdown()
        progress('stopping both nodes (SIGINT)')
        processes.stop()
    progress('both nodes stopped cleanly')
    report(folder, bag, driver.attempts)
    return 0
