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
valve_node on /clock in lockstep: publish a time, wait for the states stamped with it, go on.

The one lockstep core: `valve-sim scenario run` (ros.scenario_runner) and the test kit
(valve_sim.testing) drive valve_node with it, and so can any driver of model time.

Protocol. valve_node runs with use_sim_time and lockstep_inputs (lockstep_parameters()),
so it takes its inputs stamped with the model time they apply from (ros.lockstep_inputs).
set_flow(flow, at_ns) and set_tank_pressure(absolute, at_ns) publish a value stamped at_ns
(default: the start of the next tick); a batch may hold a value for each of its ticks.
tick(count) first publishes, for each input, its held value stamped with the batch's
end unless a stamp past the start of its last tick was already sent (the cover: it
tells the node that nothing else comes for the batch), then /clock count periods on, and
waits until the valve's state of that time has arrived here, and a message of that tick
on each wait topic (the topics that other use_sim_time nodes, such as a controller under
test, publish once per tick). valve_node does not start a tick before it has its inputs
for it, whatever the load, so the tick meant for an input applies that input: no race
between an input's topic and /clock. valve_node ticks a jump of count periods period by
period (ros.clock_jumps), a state each, so a ramp or a sine goes TICKS_PER_CLOCK ticks
per /clock like a step; the driver saves count - 1 round trips. Parameter changes go
between tick() calls and act from the next tick: the same run twice gives the same
states, bit for bit. restart() restarts the valve (its ~/restart) and the driver with
it: the next run needs no new driver, no new discovery.

A tick is complete when the last of the tick topics valve_node publishes
(valve_topics.TICK_TOPICS) has come with its stamp, and applied_inlet_flow (the
handshake), which carries the flow the tick applied (with a tank input also
applied_tank_pressure); one that applied another value than the one sent for it is an
error (LateInputError: the node rejected it, or its model is halted), never a silent
difference. /clock is subscribed best effort by rclpy's time source, so a time whose
state does not come within RESEND is published again.

The driver spins its own node on the calling thread (rclpy's EventsExecutor where
there is one), so waiting costs no thread hand-over; as fast as the node can by
default, or paced to rate times real time. Its messages (the /clock bytes, the stamped
inputs as sent, the wait topics and a controller's flow replies): ros.lockstep_protocol.
"""

import time

from builtin_interfaces.msg import Time
from rcl_interfaces.msg import Parameter as ParameterMessage
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState
from valve_sim.core.errors import IncompleteRunError, ParameterError, WaitTimeoutError
from valve_sim.core.parameter_sections import node_fqn
from valve_sim.core.parameters import NODE_NAME
from valve_sim.recording.cdr import CdrMessage
from valve_sim.recording.valve_topics import message_class, TOPIC_TYPES
from valve_sim.ros.lockstep_inputs import PARAMETER as LOCKSTEP_INPUTS, QOS as INPUT_QOS
from valve_sim.ros.lockstep_protocol import (
    announcing, answer, clock_message, FLOW_AT_END, FLOW_REPLY_TYPE, HANDSHAKE, hears_states,
    LAST_TOPIC, LateInputError, NS_PER_S, own_valve, RELIABLE, RESEND, RestartClients,
    SentInput, SPIN_SLICE, stamp_ns, START_NS, TANK_AT_END, TANK_HANDSHAKE, TANK_TOLERANCE,
    TIMEOUT, WaitTopic)
from valve_sim.ros.node_processes import spin_until
from valve_sim.ros.spinning import DEFAULT_EXECUTOR, EXECUTORS
from valve_sim.ros.valve_inputs import STAMPED_FLOW_TOPIC


def lockstep_parameters(tank=False):
    """Return valve_node's parameters {name: command-line value} for a Lockstep driver."""
    return {'use_sim_time': 'true',
            LOCKSTEP_INPUTS: 'inlet_flow,tank_pressure' if tank else 'inlet_flow'}


class Lockstep:
    """
    Drives one valve_node on /clock, tick by tick, with its inlet flow and parameters.

    context: the rclpy context; namespace: the valve's; processes: the NodeProcesses
    whose death ends a wait with an error; on_state(topic, data) receives every tick
    message of the valve when record_topics names it (bytes as published); tank: the
    driver sends tank_pressure too (set_tank_pressure).
    """

    def __init__(self, context, namespace='', processes=None, rate=None, on_state=None,
                 record_topics=(), tank=False):
        import rclpy

        with announcing():  # the nodes it starts hear of it at once (lockstep_protocol)
            self.node = rclpy.create_node('valve_lockstep', namespace=namespace or '/',
                                          context=context)
        self.executor = EXECUTORS[DEFAULT_EXECUTOR](context=context)
        self.executor.add_node(self.node)
        self.processes, self.rate = processes, rate
        self.clock = self.node.create_publisher(Clock, '/clock', 10)
        self.inlet = self.node.create_publisher(JointState, STAMPED_FLOW_TOPIC, INPUT_QOS)
        self._flow_message = CdrMessage(frame_id='')  # as applied_inlet_flow's layout
        self._flow_message.strings(['inlet_flow'])
        self._flow_message.float64s(0)  # position
        self._flow_offset = self._flow_message.float64s(1)  # velocity: the flow [m^3/s]
        self._flow_message.float64s(0)  # effort
        self.valve_name = node_fqn(namespace, NODE_NAME)
        self.parameters = AsyncParameterClient(self.node, self.valve_name)
        self.restart_clients = RestartClients(self.node, self.spin_until)
        self.wait_topics = []
        self.tank_publisher = None
        self.heard = 0  # tick messages taken, counted
        self.subscriptions = [self.node.create_subscription(
            JointState, HANDSHAKE, self._on_handshake, RELIABLE, raw=True),
            self.node.create_subscription(
                message_class(TOPIC_TYPES[LAST_TOPIC]), LAST_TOPIC, self._on_last, RELIABLE,
                raw=True)]
        handshakes = (HANDSHAKE, LAST_TOPIC)
        if tank:
            self.tank_publisher = self.node.create_publisher(FluidPressure, 'tank_pressure',
                                                             INPUT_QOS)
            self.subscriptions.append(self.node.create_subscription(
                FluidPressure, TANK_HANDSHAKE, self._on_tank, RELIABLE, raw=True))
            handshakes += (TANK_HANDSHAKE,)
        self._reset()
        for topic in record_topics:
            if topic not in handshakes:
                self.subscriptions.append(self.node.create_subscription(
                    message_class(TOPIC_TYPES[topic]), topic,
                    lambda data, topic=topic: self._on_state(topic, data), RELIABLE, raw=True))
        self.on_state = on_state
        self.record_topics = set(record_topics)

    def _reset(self):
        """Forget the run: as a new driver before start() (no input sent, no state heard)."""
        self.flows = SentInput(self._publish_flow)
        # the tank pressures [Pa absolute], with tank=True
        self.tanks = None if self.tank_publisher is None else SentInput(self._publish_tank)
        self.time_ns = None  # stamp of the valve's latest state
        self.applied = None  # the flow applied over the tick ending at time_ns [m^3/s]
        self.clock_ns = None  # last /clock published
        self.period_ns = None
        self._paced_from = None  # (wall time, clock) pacing starts from
        self._applied_ns = self._last_ns = None
        self.applied_tank = None  # the tank pressure applied over the tick ending at time_ns
        self._tank_ns = None
        for topic in self.wait_topics:
            topic.reset()

    def _on_state(self, topic, data):
        self.heard += 1
        self.on_state(topic, data)

    def _on_handshake(self, data):
        self.heard += 1
        self._applied_ns = stamp_ns(data)
        self.applied = FLOW_AT_END.unpack_from(data, len(data) - 12)[0]
        self._update_time()
        if HANDSHAKE in self.record_topics:
            self.on_state(HANDSHAKE, data)

    def _on_last(self, data):
        self.heard += 1
        self._last_ns = stamp_ns(data)
        self._update_time()
        if LAST_TOPIC in self.record_topics:
            self.on_state(LAST_TOPIC, data)

    def _on_tank(self, data):
        self.heard += 1
        self._tank_ns = stamp_ns(data)
        self.applied_tank = TANK_AT_END.unpack_from(data, len(data) - TANK_AT_END.size)[0]
        self._update_time()
        if TANK_HANDSHAKE in self.record_topics:
            self.on_state(TANK_HANDSHAKE, data)

    def _update_time(self):
        """time_ns: the latest tick the applied inputs and the tick's last topic came for."""
        stamps = (self._applied_ns, self._last_ns) + (
            (self._tank_ns,) if self.tank_publisher else ())
        if None not in stamps:
            self.time_ns = min(stamps)

    def spin_until(self, condition, what, timeout=TIMEOUT):
        """Spin until condition() holds, checking it every SPIN_SLICE (graph changes wake none)."""
        spin_until(self.executor, condition, timeout, what, self.processes, period=SPIN_SLICE)

    def connect(self, wait_topics=(), timeout=TIMEOUT):
        """
        Wait until the valve hears /clock and inlet_flow and its services answer.

        Also until each wait topic has a publisher (its type is taken from the graph), and
        until each subscription here is matched with its publisher: a state published
        before that would be lost, and the lockstep would wait for it in vain.
        """
        if self.processes is not None and 'valve_node' in self.processes.processes:
            own_valve(self.node, self.processes.processes['valve_node'].pid, self.spin_until,
                      timeout)
        self.spin_until(lambda: self.clock.get_subscription_count() > 0
                        and self.inlet.get_subscription_count() > 0
                        and (self.tank_publisher is None
                             or self.tank_publisher.get_subscription_count() > 0),
                        'valve_node subscribing /clock and its inputs', timeout)
        self.spin_until(lambda: all(s.get_publisher_count() > 0 for s in self.subscriptions),
                        'valve_node publishing its states to this driver', timeout)
        self.spin_until(self.parameters.services_are_ready, 'the parameter services of '
                        'valve_node', timeout)
        for topic in wait_topics:
            name = self.node.resolve_topic_name(topic)
            self.spin_until(lambda: self.node.count_publishers(name) > 0,
                            f'a publisher of the wait topic {name}', timeout)
            types = dict(self.node.get_topic_names_and_types())[name]
            topic = WaitTopic(self.node, name, types[0])
            self.spin_until(lambda: topic.subscription.get_publisher_count() > 0,
                            f'the wait topic {name} matched', timeout)
            if topic.flow_reply:  # it answers states: a state sent before it listens is lost
                self.spin_until(lambda: hears_states(self.node, name),
                                f'the controller of {name} subscribing a state of valve_node',
                                timeout)
            self.wait_topics.append(topic)

    def flow_reply(self, topic):
        """Return the wait topic (connected) of a controller's flow replies, or None for None."""
        if topic is None:
            return None
        name = self.node.resolve_topic_name(topic)
        wait_topic = next(topic for topic in self.wait_topics if topic.topic == name)
        if not wait_topic.flow_reply:
            raise IncompleteRunError(f'the flow topic {name} must be a {FLOW_REPLY_TYPE} stamped '
                                     'with the tick it answers, its velocity[0] the flow [m^3/s]')
        return wait_topic

    def start(self, start_ns=START_NS, period_ns=1_000_000):
        """
        Publish /clock = start_ns until the valve's first state (its model time's anchor) comes.

        Returns its stamp. Later ticks are period_ns apart. Send the inputs first
        (set_flow, set_tank_pressure): valve_node on lockstep_inputs waits for them.
        """
        self.period_ns = period_ns
        self._publish_clock(start_ns)
        self._wait_for(start_ns, 'the first state of valve_node on /clock', ())
        self._paced_from = (time.monotonic(), start_ns)
        return self.time_ns

    @property
    def flow(self):
        """Return the inlet flow sent last [m^3/s] (None before any)."""
        return self.flows.value

    @property
    def tank(self):
        """Return the tank pressure sent last [Pa absolute] (None before any or without)."""
        return None if self.tanks is None else self.tanks.value

    def _inputs(self):
        return (self.flows,) if self.tanks is None else (self.flows, self.tanks)

    def input_publishers(self):
        """Return {topic (full name): (publisher, SentInput)} of the inputs this sends."""
        pairs = [(self.inlet, self.flows)] + (
            [] if self.tanks is None else [(self.tank_publisher, self.tanks)])
        return {publisher.topic_name: (publisher, sent) for publisher, sent in pairs}

    def _next_start(self, at_ns):
        """Return an input's stamp: at_ns, by default the start of the next tick."""
        return (self.clock_ns or START_NS) if at_ns is None else at_ns

    def set_flow(self, flow, at_ns=None):
        """Send the inlet flow [m^3/s] from model time at_ns [ns] on (default: the next tick)."""
        self.flows.send(float(flow), self._next_start(at_ns))

    def set_tank_pressure(self, absolute, at_ns=None):
        """Send the tank pressure [Pa absolute] from model time at_ns [ns] on (tank=True)."""
        self.tanks.send(float(absolute), self._next_start(at_ns))

    def _publish_flow(self, flow, stamp_ns):
        self._flow_message.set_stamp(*divmod(stamp_ns, NS_PER_S))
        self._flow_message.set_float64s(self._flow_offset, flow)
        self.inlet.publish(self._flow_message.bytes())

    def _publish_tank(self, absolute, stamp_ns):
        message = FluidPressure(fluid_pressure=absolute)
        message.header.stamp = Time(sec=stamp_ns // NS_PER_S, nanosec=stamp_ns % NS_PER_S)
        self.tank_publisher.publish(message)

    def tick(self, count=1):
        """
        Advance the valve by count tick periods in one /clock; returns the last state's stamp.

        valve_node ticks a jump of up to clock_jumps.MAX_TICKS_PER_CLOCK periods period
        by period, a state each; this waits for the last. Each tick applies the input
        values stamped last at or before its start; the wait topics must have a message
        of the last.
        """
        time_ns = self.clock_ns + count * self.period_ns
        last_start = time_ns - self.period_ns
        for sent in self._inputs():
            sent.cover(last_start, time_ns)
        if self.rate:
            wall, clock = self._paced_from
            delay = wall + (time_ns - clock) / NS_PER_S / self.rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        for topic in self.wait_topics:
            topic.mark()
        self._publish_clock(time_ns)
        self._wait_for(time_ns, f'the state of valve_node at {time_ns / NS_PER_S:.6f} s',
                       self.wait_topics)
        flow = self.flows.at(last_start)
        if flow is not None and self.applied != flow:
            raise LateInputError(
                f'valve_node applied {self.applied:g} m^3/s over the tick ending at '
                f'{time_ns / NS_PER_S:.6f} s, not the {flow:g} m^3/s sent for it '
                '(valve_node rejected it, or its model is halted: see its log)'
            )
        tank = None if self.tanks is None else self.tanks.at(last_start)
        if tank is not None and abs(self.applied_tank - tank) > TANK_TOLERANCE:
            raise LateInputError(
                f'valve_node applied the tank pressure {self.applied_tank:g} Pa over the tick '
                f'ending at {time_ns / NS_PER_S:.6f} s, not the {tank:g} Pa sent for it '
                '(see its log)'
            )
        return time_ns

    def _publish_clock(self, time_ns):
        self.clock_ns = time_ns
        self.clock.publish(clock_message(time_ns))

    def _ready(self, time_ns, wait_topics):
        return self.time_ns is not None and self.time_ns >= time_ns and all(
            topic.has(time_ns) for topic in wait_topics)

    def _wait_for(self, time_ns, what, wait_topics):
        """Spin until the state at time_ns (and the wait topics' messages) came; resend /clock."""
        deadline = time.monotonic() + TIMEOUT
        while not self._ready(time_ns, wait_topics):
            resend = time.monotonic() + RESEND
            while not self._ready(time_ns, wait_topics) and time.monotonic() < resend:
                self.executor.spin_once(timeout_sec=RESEND)
            if self._ready(time_ns, wait_topics):
                return
            if self.processes is not None:
                self.processes.check(what)
            if time.monotonic() > deadline:
                missing = [t.topic for t in wait_topics if not t.has(time_ns)]
                raise WaitTimeoutError(f'no {what} within {TIMEOUT:g} s' + (
                    f' (waiting for {", ".join(missing)})' if missing else ''))
            self.clock.publish(clock_message(time_ns))

    def set_parameters(self, changes):
        """
        Set valve_node parameters {name: value} at once, between ticks.

        Raises ValueError with valve_node's reason if it refuses them.
        """
        parameters = [Parameter(name, value=value) for name, value in changes.items()]
        result = answer(lambda: self.parameters.set_parameters_atomically(parameters),
                        self.spin_until, 'the answer of valve_node to a parameter change').result
        if not result.successful:
            raise ParameterError(f'valve_node refused {changes}: {result.reason}')

    def get_parameters(self, names):
        """Return valve_node's values of names, as a dict; ValueError naming any it lacks."""
        names = list(names)
        values = self._get(names)
        if len(values) != len(names):  # one name it lacks fails the whole request
            missing = [name for name in names if len(self._get([name])) != 1]
            raise ParameterError(f"valve_node has no parameter {', '.join(map(repr, missing))}")
        return {name: Parameter.from_parameter_msg(ParameterMessage(name=name, value=value)).value
                for name, value in zip(names, values)}

    def _get(self, names):
        return answer(lambda: self.parameters.get_parameters(names), self.spin_until,
                      'the answer of valve_node to get_parameters').values

    def request_restart(self, node_name, overrides=None, timeout=TIMEOUT):
        """Call node_name's ~/restart (RestartClients.call); returns the node's reason."""
        return self.restart_clients.call(node_name, overrides, timeout)

    def restart(self, overrides=None, timeout=TIMEOUT):
        """
        Restart the valve (its ~/restart with overrides) and this driver with it; returns why.

        The driver is then as a new one connected to a new valve_node: no input sent, no
        state heard, start() next (its inputs first); it keeps its discovery (the valve,
        the wait topics: their nodes restart too, if they have to), so it sends the same
        messages, bit for bit, as a new driver would. A refused restart (ParameterError)
        changes neither. The tick messages of the run before still on their way (the
        valve's, the wait topics') are taken first: the valve published its own before
        it answered.
        """
        reason = self.request_restart(self.valve_name, overrides, timeout)
        heard = None
        while heard != self._taken():  # until a spin takes none
            heard = self._taken()
            self.executor.spin_once(timeout_sec=0)
        self._reset()
        return reason

    def _taken(self):
        """Return how many tick messages (the valve's, the wait topics') this took so far."""
        return self.heard + sum(topic.count for topic in self.wait_topics)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
