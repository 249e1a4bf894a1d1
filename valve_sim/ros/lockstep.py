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
states, bit for bit.

A tick is complete when the last of the tick topics valve_node publishes
(valve_topics.TICK_TOPICS) has come with its stamp, and applied_inlet_flow (the
handshake), which carries the flow the tick applied (with a tank input also
applied_tank_pressure); one that applied another value than the one sent for it is an
error (LateInputError: the node rejected it, or its model is halted), never a silent
difference. /clock is subscribed best effort by rclpy's time source, so a time whose
state does not come within RESEND is published again.

The driver spins its own node on the calling thread (rclpy's EventsExecutor where
there is one), so waiting costs no thread hand-over; as fast as the node can by
default, or paced to rate times real time.

Over 400 lines on purpose: Lockstep is one state machine (clock, inputs, ticks,
waits), kept in one class with its messages.
"""

import struct
import time

from builtin_interfaces.msg import Time
from rcl_interfaces.msg import Parameter as ParameterMessage
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState
from valve_sim.core.errors import IncompleteRunError, ParameterError, WaitTimeoutError
from valve_sim.core.parameter_sections import node_fqn
from valve_sim.core.parameters import NODE_NAME
from valve_sim.recording.cdr import CdrMessage, ENCAPSULATION, STAMP, STAMP_OFFSET
from valve_sim.recording.valve_topics import message_class, TICK_TOPICS, TOPIC_TYPES
from valve_sim.ros.lockstep_inputs import PARAMETER as LOCKSTEP_INPUTS, QOS as INPUT_QOS
from valve_sim.ros.node_processes import spin_until
from valve_sim.ros.spinning import DEFAULT_EXECUTOR, EXECUTORS
from valve_sim.ros.valve_inputs import STAMPED_FLOW_TOPIC


HANDSHAKE = 'applied_inlet_flow'  # the flow the tick applied
TANK_HANDSHAKE = 'applied_tank_pressure'  # the tank pressure it applied (absolute)
TANK_AT_END = struct.Struct('<dd')  # FluidPressure: fluid_pressure, variance, at its end
TANK_TOLERANCE = 1e-6  # [Pa]: the node's gauge and back to absolute may round
LAST_TOPIC = TICK_TOPICS[-1]  # published last in a tick: once it is here, the tick is
FLOW_AT_END = struct.Struct('<d')  # applied_inlet_flow: velocity[0], then an empty effort
NS_PER_S = 1_000_000_000
START_NS = NS_PER_S  # /clock of the first tick: past any timer's first period (up to 1 s)
RESEND = 0.5  # [s] without the state: publish the same /clock again (it is best effort)
TIMEOUT = 60.0  # [s] for a tick's state, a service answer, discovery
QUEUE_DEPTH = 1000
RELIABLE = QoSProfile(depth=QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)


class LateInputError(IncompleteRunError):
    """A tick applied another input value than the one sent for it."""


def lockstep_parameters(tank=False):
    """Return valve_node's parameters {name: command-line value} for a Lockstep driver."""
    return {'use_sim_time': 'true',
            LOCKSTEP_INPUTS: 'inlet_flow,tank_pressure' if tank else 'inlet_flow'}


class SentInput:
    """
    One stamped input as the driver sends it: publish(value, stamp_ns), and what a tick applies.

    Stamps never go back (a later stamp is the node's proof that it has them all); a
    value sent again at the same stamp replaces the one before, at the node too.
    """

    def __init__(self, publish):
        self.publish = publish
        self.sent = []  # [(stamp [ns], value)] from the oldest a tick may still apply
        self.count = 0  # messages sent

    @property
    def value(self):
        """Return the value sent last (None before any)."""
        return self.sent[-1][1] if self.sent else None

    def send(self, value, stamp_ns):
        if self.sent and stamp_ns < self.sent[-1][0]:
            raise ValueError(f'an input stamped {stamp_ns / NS_PER_S:.6f} s after one stamped '
                             f'{self.sent[-1][0] / NS_PER_S:.6f} s: stamps never go back')
        self.publish(value, stamp_ns)
        self.sent.append((stamp_ns, value))
        self.count += 1

    def cover(self, last_start_ns, end_ns):
        """Send the held value stamped end_ns unless a stamp past last_start_ns went already."""
        if self.sent and self.sent[-1][0] <= last_start_ns:
            self.send(self.sent[-1][1], end_ns)

    def at(self, time_ns):
        """Return the value the tick starting at time_ns applies; forget the older ones."""
        index = max((i for i, (stamp, _) in enumerate(self.sent) if stamp <= time_ns),
                    default=None)
        if index is None:
            return None  # none sent: nothing to check
        del self.sent[:index]
        return self.sent[0][1]


def stamp_ns(data):
    """Return the header stamp [ns] of a message's CDR bytes (every tick message has one)."""
    sec, nanosec = STAMP.unpack_from(data, STAMP_OFFSET)
    return sec * NS_PER_S + nanosec


def clock_message(time_ns):
    """
    Return a rosgraph_msgs/Clock of time_ns as its CDR bytes, which rclpy publishes as they are.

    Built directly (a Time is the whole message): an rclpy message built and serialized
    costs the driver about ten times as much on every tick.
    """
    return ENCAPSULATION + STAMP.pack(*divmod(time_ns, NS_PER_S))


class WaitTopic:
    """A topic another node publishes once per tick: stamped (header) or counted."""

    def __init__(self, node, topic, type_name):
        message_type = message_class(type_name)
        fields = list(message_type.get_fields_and_field_types().items())
        self.topic = topic
        self.stamped = bool(fields) and fields[0] == ('header', 'std_msgs/Header')
        self.latest_ns, self.count, self.count_before = None, 0, 0
        self.subscription = node.create_subscription(message_type, topic, self._on_message,
                                                     RELIABLE, raw=True)

    def _on_message(self, data):
        self.count += 1
        if self.stamped:
            self.latest_ns = stamp_ns(data)

    def mark(self):
        """Note that a tick's /clock goes out: an unstamped topic's next message is that tick's."""
        self.count_before = self.count

    def has(self, time_ns):
        """Whether the message of the tick at time_ns has come (unstamped: one since mark())."""
        if self.stamped:
            return self.latest_ns is not None and self.latest_ns >= time_ns
        return self.count > self.count_before


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
        self.flows = SentInput(self._publish_flow)
        self.tanks = None  # the tank pressures [Pa absolute], with tank=True
        self.parameters = AsyncParameterClient(self.node, node_fqn(namespace, NODE_NAME))
        self.wait_topics = []
        self.time_ns = None  # stamp of the valve's latest state
        self.applied = None  # the flow applied over the tick ending at time_ns [m^3/s]
        self.clock_ns = None  # last /clock published
        self.period_ns = None
        self._paced_from = None  # (wall time, clock) pacing starts from
        self._applied_ns = self._last_ns = None
        self.applied_tank = None  # the tank pressure applied over the tick ending at time_ns
        self._tank_ns = None
        self.tank_publisher = None
        self.subscriptions = [self.node.create_subscription(
            JointState, HANDSHAKE, self._on_handshake, RELIABLE, raw=True),
            self.node.create_subscription(
                message_class(TOPIC_TYPES[LAST_TOPIC]), LAST_TOPIC, self._on_last, RELIABLE,
                raw=True)]
        handshakes = (HANDSHAKE, LAST_TOPIC)
        if tank:
            self.tank_publisher = self.node.create_publisher(FluidPressure, 'tank_pressure',
                                                             INPUT_QOS)
            self.tanks = SentInput(self._publish_tank)
            self.subscriptions.append(self.node.create_subscription(
                FluidPressure, TANK_HANDSHAKE, self._on_tank, RELIABLE, raw=True))
            handshakes += (TANK_HANDSHAKE,)
        for topic in record_topics:
            if topic not in handshakes:
                self.subscriptions.append(self.node.create_subscription(
                    message_class(TOPIC_TYPES[topic]), topic,
                    lambda data, topic=topic: on_state(topic, data), RELIABLE, raw=True))
        self.on_state = on_state
        self.record_topics = set(record_topics)

    def _on_handshake(self, data):
        self._applied_ns = stamp_ns(data)
        self.applied = FLOW_AT_END.unpack_from(data, len(data) - 12)[0]
        self._update_time()
        if HANDSHAKE in self.record_topics:
            self.on_state(HANDSHAKE, data)

    def _on_last(self, data):
        self._last_ns = stamp_ns(data)
        self._update_time()
        if LAST_TOPIC in self.record_topics:
            self.on_state(LAST_TOPIC, data)

    def _on_tank(self, data):
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
        spin_until(self.executor, condition, timeout, what, self.processes, period=RESEND)

    def connect(self, wait_topics=(), timeout=TIMEOUT):
        """
        Wait until the valve hears /clock and inlet_flow and its services answer.

        Also until each wait topic has a publisher (its type is taken from the graph), and
        until each subscription here is matched with its publisher: a state published
        before that would be lost, and the lockstep would wait for it in vain.
        """
        self.spin_until(lambda: self.clock.get_subscription_count() > 0
                        and self.inlet.get_subscription_count() > 0
                        and (self.tank_publisher is None
                             or self.tank_publisher.get_subscription_count() > 0),
                        'valve_node subscribing /clock and its inputs', timeout)
        self.spin_until(lambda: all(s.get_publisher_count() > 0 for s in self.subscriptions),
                        'valve_node publishing its states to this driver', timeout)
        if not self.parameters.wait_for_services(timeout_sec=timeout):
            raise WaitTimeoutError(f'no parameter services of valve_node within {timeout:g} s')
        for topic in wait_topics:
            name = self.node.resolve_topic_name(topic)
            self.spin_until(lambda: self.node.count_publishers(name) > 0,
                            f'a publisher of the wait topic {name}', timeout)
            types = dict(self.node.get_topic_names_and_types())[name]
            topic = WaitTopic(self.node, name, types[0])
            self.spin_until(lambda: topic.subscription.get_publisher_count() > 0,
                            f'the wait topic {name} matched', timeout)
            self.wait_topics.append(topic)

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
        future = self.parameters.set_parameters_atomically(
            [Parameter(name, value=value) for name, value in changes.items()])
        self.spin_until(future.done, 'the answer of valve_node to a parameter change')
        result = future.result().result
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
        future = self.parameters.get_parameters(names)
        self.spin_until(future.done, 'the answer of valve_node to get_parameters')
        return future.result().values

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
