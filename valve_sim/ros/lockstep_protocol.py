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
The lockstep protocol's messages on the driver's side: /clock, stamped inputs, wait topics.

What ros.lockstep's driver sends and hears, apart from its state machine: the /clock
bytes (clock_message), a tick message's stamp (stamp_ns), the stamped inputs as sent
(SentInput: stamps never go back; the value each tick applies), the graph checks of
its connect (own_valve, hears_states), the clients of nodes' ~/restart (RestartClients),
and the topics other
use_sim_time nodes publish once per tick (WaitTopic; with FLOW_REPLY_TYPE, a
controller's flow reply, stamped with the tick it answers). The valve's side of the
same protocol: ros.lockstep_inputs.
"""

import contextlib
import hashlib
import os
from pathlib import Path
import struct
import tempfile
import time

from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from valve_sim.core.errors import (IncompleteRunError, ParameterError, ValveSimError,
                                   WaitTimeoutError)
from valve_sim.recording.cdr import ENCAPSULATION, read_message, STAMP, STAMP_OFFSET
from valve_sim.recording.valve_topics import message_class, TICK_TOPICS


HANDSHAKE = 'applied_inlet_flow'  # the flow the tick applied
TANK_HANDSHAKE = 'applied_tank_pressure'  # the tank pressure it applied (absolute)
TANK_AT_END = struct.Struct('<dd')  # FluidPressure: fluid_pressure, variance, at its end
TANK_TOLERANCE = 1e-6  # [Pa]: the node's gauge and back to absolute may round
LAST_TOPIC = TICK_TOPICS[-1]  # published last in a tick: once it is here, the tick is
FLOW_AT_END = struct.Struct('<d')  # applied_inlet_flow: velocity[0], then an empty effort
NS_PER_S = 1_000_000_000
START_NS = NS_PER_S  # /clock of the first tick: past any timer's first period (up to 1 s)
RESEND = 0.5  # [s] without the state: publish the same /clock again (it is best effort)
SPIN_SLICE = 0.01  # [s] between checks of a wait's condition (a graph change wakes no spin)
TIMEOUT = 60.0  # [s] for a tick's state, a service answer, discovery
# [s] a service request not answered by then is sent again: under load Fast DDS may drop an
# answer (its server waits only briefly for the client's reply reader to match, rmw_fastrtps)
ANSWER_RESEND = 2.0
QUEUE_DEPTH = 1000
RELIABLE = QoSProfile(depth=QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
FAST_DDS_VENDOR = b'\x01\x0f'  # an endpoint GID's first bytes under Fast DDS (eProsima)
# a controller's flow reply: valve_node's own stamped-flow layout, velocity[0] [m^3/s]
FLOW_REPLY_TYPE = 'sensor_msgs/msg/JointState'
# Fast DDS announces a new participant a few times at its start, then every 3 s. A driver's
# participant is up before the nodes it starts: theirs miss its first announcements and learn
# of it at its next (3 of 5 scenario starts waited ~3 s for discovery, none of 5 with this),
# so a driver's participant announces itself every 50 ms over its first 5 s.
ANNOUNCING_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="valve_sim_driver" is_default_profile="true">
    <rtps><builtin><discovery_config><initialAnnouncements>
      <count>100</count><period><sec>0</sec><nanosec>50000000</nanosec></period>
    </initialAnnouncements></discovery_config></builtin></rtps>
  </participant>
</profiles>
"""
PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


@contextlib.contextmanager
def announcing():
    """
    Within it, a Fast DDS participant announces itself often at first (ANNOUNCING_PROFILE).

    Fast DDS reads its profile file when a process creates its first participant (here
    a driver's, at its node): a process that created one before keeps its settings, and
    so does a user's own profile file (either variable set). The nodes a driver starts
    after it do not inherit the variables.
    """
    if any(os.environ.get(name) for name in PROFILE_VARIABLES):
        yield
        return
    digest = hashlib.sha256(ANNOUNCING_PROFILE.encode()).hexdigest()[:12]
    path = Path(tempfile.gettempdir()) / f'valve_sim_announcing_{digest}.xml'
    if not path.is_file():  # written whole, then renamed: another process may read it
        partial = path.with_name(f'{path.name}.{os.getpid()}')
        partial.write_text(ANNOUNCING_PROFILE)
        os.replace(partial, path)
    os.environ.update(dict.fromkeys(PROFILE_VARIABLES, str(path)))
    try:
        yield
    finally:
        for name in PROFILE_VARIABLES:
            os.environ.pop(name, None)


class LateInputError(IncompleteRunError):
    """A tick applied another input value than the one sent for it."""


class StampOrderError(ValveSimError, ValueError):
    """An input was sent stamped before one sent already: the driver's caller's mistake."""


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
            raise StampOrderError(
                f'an input stamped {stamp_ns / NS_PER_S:.6f} s after one stamped '
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


def gid_process(gid):
    """
    Return the low 16 bits of the PID of the process an endpoint's GID belongs to, or None.

    Fast DDS writes them into bytes 4-5 of each participant's GUID prefix (little
    endian); None under another middleware.
    """
    gid = bytes(gid)
    return int.from_bytes(gid[4:6], 'little') if gid[:2] == FAST_DDS_VENDOR else None


def answer(call, spin_until, what, timeout=TIMEOUT):
    """
    Return the answer to the request that call() sends, sending it again while none comes.

    call() sends a request and returns its future; spin_until(condition, what, timeout):
    the driver's wait. For requests whose repetition changes nothing more (parameters
    read or set to the same values, a ~/restart), so that a dropped answer (ANSWER_RESEND)
    costs seconds, not the whole timeout. Raises WaitTimeoutError after timeout.
    """
    deadline, sent = time.monotonic() + timeout, 0
    while True:
        future, sent = call(), sent + 1
        try:
            spin_until(future.done, what, max(min(ANSWER_RESEND, deadline - time.monotonic()), 0))
            return future.result()
        except WaitTimeoutError as error:
            future.cancel()  # its answer, if it still comes, is dropped (rclpy's Client)
            if time.monotonic() >= deadline:
                raise WaitTimeoutError(
                    f'no {what} within {timeout:g} s ({sent} requests sent)') from error


class RestartClients:
    """
    The clients of nodes' ~/restart (rcl_interfaces/srv/SetParametersAtomically), kept.

    node: the driver's; spin_until(condition, what, timeout): the driver's wait. One
    client per node, made at its first call and kept for the driver's life.
    """

    def __init__(self, node, spin_until):
        self.node, self.spin_until, self.clients = node, spin_until, {}

    def call(self, node_name, overrides=None, timeout=TIMEOUT):
        """
        Call the ~/restart of node_name (its full name) with overrides {name: value}.

        Returns the node's reason; ParameterError with it if it refuses (the node is
        then unchanged).
        """
        from rcl_interfaces.srv import SetParametersAtomically

        if node_name not in self.clients:
            self.clients[node_name] = self.node.create_client(
                SetParametersAtomically, f'{node_name}/restart')
        client = self.clients[node_name]
        self.spin_until(client.service_is_ready, f'the service {node_name}/restart', timeout)
        request = SetParametersAtomically.Request(parameters=[
            Parameter(name, value=value).to_parameter_msg()
            for name, value in (overrides or {}).items()])
        result = answer(lambda: client.call_async(request), self.spin_until,
                        f'the answer of {node_name} to ~/restart', timeout).result
        if not result.successful:
            raise ParameterError(result.reason)
        return result.reason


def own_valve(node, pid, spin_until, timeout):
    """
    Wait for the valve_node of process pid; IncompleteRunError if another answers here too.

    Before any /clock: a valve_node another run left in this ROS domain would answer
    this run's ticks while its own still starts. Under Fast DDS each publisher's GID
    names its process (gid_process); under another middleware this is not checked.
    spin_until(condition, what, timeout): the driver's.
    """
    topic = node.resolve_topic_name(HANDSHAKE)

    def publishers():
        return [gid_process(info.endpoint_gid)
                for info in node.get_publishers_info_by_topic(topic)]

    spin_until(lambda: (pid & 0xFFFF) in publishers() or None in publishers(),
               'valve_node of this run publishing', timeout)
    others = [process for process in publishers() if process != pid & 0xFFFF]
    if others and None not in others:
        raise IncompleteRunError(
            f'{len(others)} other valve_node(s) in this ROS domain publish {topic} '
            f'(process {others[0]} mod 65536): nodes of another run are up here; stop '
            'them or run in a domain of its own')


def hears_states(node, topic):
    """
    Whether a node publishing topic subscribes to a topic that valve_node publishes.

    An endpoint can be known before its node's name (namespace still ''): not yet.
    """
    nodes = {(info.node_namespace, info.node_name)
             for info in node.get_publishers_info_by_topic(topic)}
    valves = {(info.node_namespace, info.node_name) for info in
              node.get_publishers_info_by_topic(node.resolve_topic_name(HANDSHAKE))
              if info.node_namespace.startswith('/')}
    states = {name for namespace, valve in valves for name, _ in
              node.get_publisher_names_and_types_by_node(valve, namespace)}
    return any((info.node_namespace, info.node_name) in nodes for state in states
               for info in node.get_subscriptions_info_by_topic(state))


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
    """
    A topic another node publishes once per tick: stamped (header) or counted.

    A stamped topic of FLOW_REPLY_TYPE is a controller's flow reply: replies keeps its
    velocity[0] [m^3/s] by stamp until reply(time_ns) takes it.
    """

    def __init__(self, node, topic, type_name):
        message_type = message_class(type_name)
        fields = list(message_type.get_fields_and_field_types().items())
        self.topic = topic
        self.stamped = bool(fields) and fields[0] == ('header', 'std_msgs/Header')
        self.flow_reply = self.stamped and type_name.replace('/msg/', '/') == (
            FLOW_REPLY_TYPE.replace('/msg/', '/'))
        self.latest_ns, self.count, self.count_before = None, 0, 0
        self.replies = {}  # {stamp [ns]: flow [m^3/s]} not yet taken
        self.subscription = node.create_subscription(message_type, topic, self._on_message,
                                                     RELIABLE, raw=True)

    def _on_message(self, data):
        self.count += 1
        if self.stamped:
            self.latest_ns = stamp_ns(data)
        if self.flow_reply:
            message = read_message(FLOW_REPLY_TYPE, data)
            if message is not None and len(message.velocity) == 1:
                self.replies[self.latest_ns] = message.velocity[0]

    def reset(self):
        """Forget the stamps and replies heard (the nodes restart with a new time base)."""
        self.latest_ns, self.count_before = None, self.count
        self.replies.clear()

    def mark(self):
        """Note that a tick's /clock goes out: an unstamped topic's next message is that tick's."""
        self.count_before = self.count

    def has(self, time_ns):
        """Whether the message of the tick at time_ns has come (unstamped: one since mark())."""
        if self.stamped:
            return self.latest_ns is not None and self.latest_ns >= time_ns
        return self.count > self.count_before

    def reply(self, time_ns):
        """
        Return the flow [m^3/s] the reply stamped time_ns carries; forget older replies.

        Raises IncompleteRunError if no reply carries that stamp (the controller
        skipped the tick or stamped it otherwise, or its message has no one velocity).
        """
        flow = self.replies.pop(time_ns, None)
        for stamp in [stamp for stamp in self.replies if stamp < time_ns]:
            del self.replies[stamp]
        if flow is None:
            raise IncompleteRunError(
                f'no flow reply on {self.topic} stamped {time_ns / NS_PER_S:.6f} s (a '
                f'{FLOW_REPLY_TYPE} with one velocity [m^3/s], stamped with the tick it '
                'answers)')
        return flow
