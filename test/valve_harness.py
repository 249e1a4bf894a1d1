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
Drive valve_node over DDS from a test: the node runs in its own process, a probe node here.

The probe records everything the valve publishes (as plain floats, keyed by the
header stamp in ns), counts any non-finite field, and wraps the inlet_flow
topic, /clock, the parameter services and ~/reset. Its executor (the events
executor where rclpy has one, as valve_node uses) spins in a background thread;
a test waits for a condition on what arrived, checked every
POLL_INTERVAL, so tests never depend on how fast this machine is, only on
generous timeouts. flushed() counts what a recording node has written so far.
"""

from contextlib import contextmanager
import math
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import threading
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter as ParameterMessage
import rclpy
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger
from valve_sim.recording.bag import BagReader
from valve_sim.recording.valve_topics import PRESSURE_TOPICS
from valve_sim.ros.spinning import DEFAULT_EXECUTOR, EXECUTORS


REPO = Path(__file__).resolve().parent.parent
NODE_NAME = 'relief_valve'
TIMEOUT = 60.0  # [s] for anything that waits: start-up, discovery, a service answer
# [messages] per tick topic: the probe's callbacks run in Python beside the test; on a
# machine loaded to 17 they fell more than 1 s (1000 messages) behind and lost samples
PROBE_QUEUE_DEPTH = 10_000
# The probe takes 6,000 messages/s. On the SingleThreadedExecutor, whose Python wait set
# is rebuilt for every message, it took 500-650 supply samples/s with both cores busy,
# fell up to a minute behind and answered services 15-70 s late; the events executor
# (C++) keeps it current: bench/bench_probe.py measures both.
PROBE_EXECUTOR = EXECUTORS[DEFAULT_EXECUTOR]
# [s] how often a wait checks its condition. Waking the waiting test thread on every
# message instead (6 kHz) starved the probe's executor of the GIL: it fell more than
# 1000 messages behind and lost samples, even at load 4.
POLL_INTERVAL = 0.01


def start_node(log_path, *ros_args, options=()):
    """
    Start valve_node in its own process, output to log_path.

    The command: python -m valve_sim.ros.valve_node_main *options --ros-args ...
    """
    env = dict(
        os.environ,
        PYTHONUNBUFFERED='1',
        PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get('PYTHONPATH')])),
    )
    with open(log_path, 'w') as log:
        return subprocess.Popen(
            [sys.executable, '-m', 'valve_sim.ros.valve_node_main', *options,
             '--ros-args', *ros_args],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
            cwd=REPO,
        )


def flushed(bag, topics=None):
    """Return the messages (on topics) in the bag's complete chunks; 0 while the file is empty."""
    return sum(1 for _ in BagReader(bag).messages(topics)) if bag.stat().st_size else 0


class Recorder:
    """An analyser_node process recording into folder, in namespace."""

    def __init__(self, folder, namespace):
        self.folder = folder
        self.process = subprocess.Popen(
            [sys.executable, '-m', 'valve_sim.ros.analyser_node', '--ros-args',
             '-r', f'__ns:={namespace}', '-p', f'output_dir:={folder}'],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )

    def stop(self, sig=signal.SIGTERM):
        """End the recording with sig; returns the analyser's log (exit code: process)."""
        if self.process.poll() is None:
            self.process.send_signal(sig)
        return self.process.communicate(timeout=TIMEOUT)[0]


def stop_node(process, sig=signal.SIGINT):
    """Send sig and return the exit code (kills after TIMEOUT)."""
    if process.poll() is None:
        process.send_signal(sig)
        try:
            process.wait(timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    return process.returncode


@contextmanager
def running_valve(
    context,
    log_path,
    *ros_args,
    namespace='/',
    node_name=NODE_NAME,
    options=(),
    use_sim_time=False,
    stop_signal=signal.SIGINT,
    probe_executor=PROBE_EXECUTOR,
):
    """
    Run valve_node (start_node's arguments, in namespace) with a connected Probe.

    Yields (process, probe). On the way out: the node must still run and never have
    published a NaN or inf, and after stop_signal it must exit with code 0.
    """
    if namespace != '/':
        ros_args = ('-r', f'__ns:={namespace}', *ros_args)
    if use_sim_time:
        ros_args = ('-p', 'use_sim_time:=true', *ros_args)
    process = start_node(log_path, *ros_args, options=options)
    probe = Probe(context, namespace, node_name, probe_executor)
    try:
        probe.wait_until_connected(use_sim_time)
        yield process, probe
        assert process.poll() is None, f'valve_node died:\n{log_path.read_text()}'
        assert probe.non_finite == 0, 'a NaN or inf was published'
    finally:
        probe.close()
        exit_code = stop_node(process, stop_signal)
    assert exit_code == 0, f'valve_node exit code {exit_code}:\n{log_path.read_text()}'


def stamp_ns(header):
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def stamp_time(time_ns):
    return Time(sec=time_ns // 1_000_000_000, nanosec=time_ns % 1_000_000_000)


class SpinningNode:
    """A test-side node whose executor spins it in a background thread until close()."""

    def spin_in_background(self, context, executor):
        """Add self.node to a new executor (a class) and spin it in a daemon thread."""
        self.executor = executor(context=context)
        self.executor.add_node(self.node)
        self.closing = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while not self.closing.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self):
        """Stop the spin thread, then the executor and the node (shutdown under a spin fails)."""
        self.closing.set()
        self.thread.join(TIMEOUT)
        self.executor.shutdown()
        self.node.destroy_node()


class Probe(SpinningNode):
    """
    Test-side node: records the valve's outputs and drives its inputs and services.

    The probe lives in the valve's namespace, so relative topic names match;
    executor is the class of executor it spins on.
    """

    def __init__(self, context, namespace='/', node_name=NODE_NAME, executor=PROBE_EXECUTOR):
        self.node = rclpy.create_node('valve_probe', namespace=namespace, context=context)
        self.valve_name = f'{namespace.rstrip("/")}/{node_name}'
        self.condition = threading.Condition()
        self.pressures = {topic: [] for topic in PRESSURE_TOPICS}  # [(stamp_ns, p [Pa abs])]
        self.joints = []  # [(stamp_ns, x, y, x_dot, y_dot)]
        self.applied = []  # [(stamp_ns, q_in)]
        self.diagnostics = []  # [{key: value}] of this node's status
        self.non_finite = 0  # published fields that were NaN or inf
        self.clock_ns = None  # last /clock sent [ns]
        self.period_ns = None  # tick period [ns] on simulated time (start_clock), else None
        for topic in PRESSURE_TOPICS:
            self.node.create_subscription(
                FluidPressure, topic, self._pressure_callback(topic), PROBE_QUEUE_DEPTH
            )
        joint_topics = {'joint_states': self._on_joints, 'applied_inlet_flow': self._on_applied}
        for topic, callback in joint_topics.items():
            self.node.create_subscription(JointState, topic, callback, PROBE_QUEUE_DEPTH)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)
        self.inlet = self.node.create_publisher(Float64, 'inlet_flow', 100)
        self.clock = self.node.create_publisher(Clock, '/clock', 10)
        self.parameters = AsyncParameterClient(self.node, self.valve_name)
        self.reset_client = self.node.create_client(Trigger, f'{self.valve_name}/reset')
        self.spin_in_background(context, executor)

    # --- recording --------------------------------------------------------------------------

    def _record(self, target, row):
        with self.condition:
            if not all(math.isfinite(value) for value in row[1:]):
                self.non_finite += 1
            target.append(row)

    def _pressure_callback(self, topic):
        def callback(message):
            self._record(self.pressures[topic], (stamp_ns(message.header), message.fluid_pressure))

        return callback

    def _on_joints(self, message):
        self._record(self.joints, (stamp_ns(message.header), *message.position, *message.velocity))

    def _on_applied(self, message):
        self._record(self.applied, (stamp_ns(message.header), *message.velocity))

    def _on_diagnostics(self, message):
        for status in message.status:
            if status.hardware_id == self.valve_name:
                values = {kv.key: kv.value for kv in status.values}
                values.update(level=status.level[0], message=status.message, name=status.name)
                with self.condition:
                    self.diagnostics.append(values)

    def _wait(self, condition, timeout):
        """
        Block until condition() holds (checked every POLL_INTERVAL) or timeout [s].

        Returns whether it holds.
        """
        deadline = time.monotonic() + timeout
        with self.condition:
            while not condition():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.condition.wait(min(left, POLL_INTERVAL))
            return True

    def wait_for(self, condition, what, timeout=TIMEOUT):
        """Block until condition() holds; AssertionError after timeout [s]."""
        assert self._wait(condition, timeout), f'timed out after {timeout} s waiting for {what}'

    def latest(self, topic='supply_pressure'):
        with self.condition:
            return self.pressures[topic][-1]

    def count(self):
        with self.condition:
            return len(self.pressures['supply_pressure'])

    def _rows(self, topic):
        """Return the list of received rows of a tick topic."""
        others = {'joint_states': self.joints, 'applied_inlet_flow': self.applied}
        return others[topic] if topic in others else self.pressures[topic]

    def wait_for_new_samples(self, n=1, topic='supply_pressure'):
        """Wait until n more samples of topic arrived; returns the last one."""
        rows = self._rows(topic)
        with self.condition:
            start = len(rows)
        self.wait_for(lambda: len(rows) >= start + n, f'{n} new {topic} messages')
        with self.condition:
            return rows[-1]

    def wait_for_diagnostics(self, condition=lambda values: True, what='diagnostics'):
        """Wait for a diagnostics status from now on satisfying condition; returns its values."""
        with self.condition:
            start = len(self.diagnostics)
        self.wait_for(lambda: any(condition(d) for d in self.diagnostics[start:]), what)
        with self.condition:
            return next(d for d in self.diagnostics[start:] if condition(d))

    # --- driving ----------------------------------------------------------------------------

    def wait_until_connected(self, use_sim_time=False):
        """
        Wait for discovery.

        The valve hears inlet_flow (and /clock), the probe hears it, services answer.
        """
        self.wait_for(
            lambda: self.inlet.get_subscription_count() > 0, 'valve_node subscribing inlet_flow'
        )
        if use_sim_time:
            self.wait_for(
                lambda: self.clock.get_subscription_count() > 0, 'valve_node subscribing /clock'
            )
        else:
            self.wait_for(
                lambda: len(self.pressures['supply_pressure']) > 0, 'supply_pressure messages'
            )
        assert self.parameters.wait_for_services(timeout_sec=TIMEOUT), 'parameter services'
        assert self.reset_client.wait_for_service(timeout_sec=TIMEOUT), 'reset service'

    def send_flow(self, flow):
        """Publish an inlet flow [m^3/s]."""
        self.inlet.publish(Float64(data=flow))

    def send_clock(self, time_ns):
        """Publish /clock = time_ns [ns]; remembered as clock_ns."""
        self.clock_ns = time_ns
        self.clock.publish(Clock(clock=stamp_time(time_ns)))

    def start_clock(self, start_ns, period_ns):
        """
        Publish /clock from start_ns, a period at a time, until the valve's first state arrives.

        Returns that state's stamp [ns]: the valve anchors its model time at its first tick.
        From then on the probe drives the valve one period_ns at a time (next_tick).
        """
        self.period_ns = period_ns
        deadline = time.monotonic() + TIMEOUT
        time_ns = start_ns
        self.send_clock(time_ns)
        while not self._wait(lambda: self.applied, 1.0):
            assert time.monotonic() < deadline, 'valve_node never ticked on /clock'
            time_ns += period_ns
            self.send_clock(time_ns)
        return self.applied[0][0]

    def tick_at(self, time_ns):
        """
        Lockstep: publish /clock = time_ns until the valve's state stamped time_ns arrived.

        /clock is best effort, so it is sent again every second while waiting.
        """

        def published():
            return all(
                rows and rows[-1][0] >= time_ns
                for rows in (self.pressures['supply_pressure'], self.joints, self.applied)
            )

        deadline = time.monotonic() + TIMEOUT
        self.send_clock(time_ns)
        while not self._wait(published, 1.0):
            assert time.monotonic() < deadline, f'no valve state stamped {time_ns} ns'
            self.send_clock(time_ns)

    def run_until(self, end_ns):
        """Lockstep the valve through every tick period up to end_ns [ns] (simulated time)."""
        while self.clock_ns < end_ns:
            self.tick_at(self.clock_ns + self.period_ns)

    def next_tick(self):
        """Let the valve tick once more: on simulated time drive it, else wait for it."""
        if self.period_ns is None:
            self.wait_for_new_samples(topic='applied_inlet_flow')
        else:
            self.tick_at(self.clock_ns + self.period_ns)

    def _result(self, future):
        done = threading.Event()
        future.add_done_callback(lambda _: done.set())
        assert done.wait(TIMEOUT), 'service call timed out'
        return future.result()

    def set_parameters(self, **values):
        """Set parameters one by one (SetParameters service); returns the SetParametersResults."""
        parameters = [Parameter(name, value=value) for name, value in values.items()]
        return self._result(self.parameters.set_parameters(parameters)).results

    def set_parameters_atomically(self, **values):
        parameters = [Parameter(name, value=value) for name, value in values.items()]
        return self._result(self.parameters.set_parameters_atomically(parameters)).result

    def get_parameters(self, *names):
        """Return the current values of names, as a dict."""
        values = self._result(self.parameters.get_parameters(list(names))).values
        return {
            name: Parameter.from_parameter_msg(ParameterMessage(name=name, value=value)).value
            for name, value in zip(names, values)
        }

    def call_reset(self):
        """
        Call ~/reset.

        Returns (model time [ns], inlet flow [m^3/s]) of the reset state, as its
        response states them, or raises AssertionError with the refusal.
        """
        response = self._result(self.reset_client.call_async(Trigger.Request()))
        assert response.success, response.message
        seconds = re.search(r'model time (\d+)\.(\d{9}) s', response.message)
        flow = re.search(r'steady state of (\S+) m\^3/s', response.message)
        return int(seconds[1]) * 1_000_000_000 + int(seconds[2]), float(flow[1])

    def reset(self):
        """Call ~/reset; returns the model time [ns] of the reset state (from the response)."""
        return self.call_reset()[0]

    def restore(self, parameters, flow):
        """
        Bring the valve to a known state and assert it got there.

        The known state: parameters ({name: value}) in use, the inlet flow [m^3/s]
        applied, and the exact steady state of that flow. The reset is repeated until
        its response shows it happened at flow (the flow message may still be on
        its way), and the call returns only once a sample of every tick topic
        stamped after the reset has arrived: from then on the probe's latest
        samples are the restored valve's, however far its queues lagged. On
        simulated time the probe ticks the valve itself (next_tick), and the
        restored valve has published exactly one state since the reset. Returns
        the reset's model time [ns].
        """
        current = self.get_parameters(*parameters)
        changed = {name: value for name, value in parameters.items() if current[name] != value}
        if changed:
            result = self.set_parameters_atomically(**changed)
            assert result.successful, f'restoring {changed}: {result.reason}'
        assert self.get_parameters(*parameters) == parameters, 'parameters not restored'
        deadline = time.monotonic() + TIMEOUT
        while True:
            self.send_flow(flow)
            reset_ns, reset_flow = self.call_reset()
            if math.isclose(reset_flow, flow, rel_tol=1e-5, abs_tol=1e-12):
                break
            assert time.monotonic() < deadline, f'the valve never took inlet_flow {flow:g}'
            self.next_tick()
        if self.period_ns is not None:
            self.next_tick()
        for topic in PRESSURE_TOPICS:
            self.first_after(reset_ns, topic)
        self.first_after(reset_ns, 'joint_states')
        applied = self.first_after(reset_ns, 'applied_inlet_flow')
        assert applied[1] == flow, f'applied_inlet_flow after the reset: {applied[1]:g} m^3/s'
        return reset_ns

    def first_after(self, time_ns, topic='supply_pressure'):
        """Return the first sample of topic stamped after time_ns [ns] (waits for it)."""
        rows = self._rows(topic)
        self.wait_for(lambda: rows and rows[-1][0] > time_ns, f'{topic} after {time_ns} ns')
        with self.condition:
            return next(row for row in rows if row[0] > time_ns)
