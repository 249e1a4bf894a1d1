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
analyser_node's start snapshot: valve_node's parameter values, read once, written to the bag.

valve_node declares its parameters before an analyser's /parameter_events subscription
matches (always so in a lockstep run, and for an analyser started after the valve), so
the recording would lack the values a later change is compared with: a parameter set to
its own value would count as a change (analysis.steps.input_events). When a recording
starts on a node that publishes the supply-pressure topic (valve_node, in the namespace
its events are read from), StartParameters asks that node once for every parameter
(its rcl_interfaces list_parameters and get_parameters services) and writes the answer
to the bag as one rcl_interfaces/msg/ParameterEvent on /parameter_events: node = the
node's full name, new_parameters = its values (a declaration: no event), stamp = the
node's clock when asked. It goes through the recorder as a received message does, so
the live analysis and every reader of the bag (`analyse`, the scenario report, the kit)
take it at the same place in the history, before any change recorded after it.
"""

import time

from rcl_interfaces.msg import Parameter, ParameterEvent
from rcl_interfaces.srv import GetParameters, ListParameters
from rclpy.serialization import serialize_message
from valve_sim.core.parameter_sections import node_fqn
from valve_sim.ros.lockstep_protocol import ANSWER_RESEND


STATUS_KEY = 'start parameters'  # the recording status's key: whose values were read


class Read:
    """One node's read under way: its two clients, the call waited for, when asked, the names."""

    def __init__(self, clients):
        self.lister, self.getter = clients
        self.future, self.stamp_ns, self.names = None, None, None
        self.sent = None  # time.monotonic() of the request waited for

    def send(self, future):
        """Wait for future, the answer to the request just sent."""
        self.future, self.sent = future, time.monotonic()


class StartParameters:
    """
    Reads each supply-pressure publisher's parameters once; hands the ParameterEvent to write.

    node: the analyser node (its clients); supply_topic: the supply-pressure topic's full
    name; write(data, received_ns): writes a serialized ParameterEvent as received on
    /parameter_events; clients: {node full name: (list client, get client)}, the
    node's, kept across its recordings (a new client waits for discovery again). poll()
    starts a read of each new publisher and advances each a step (from the discovery
    timer), advance() the reads under way only (from every drain, so an answer is acted
    on within a drain period); no callback, no blocking; read: {node full name: number
    of parameters written}.
    """

    def __init__(self, node, supply_topic, write, clients):
        self.node, self.supply_topic, self.write = node, supply_topic, write
        self.clients = clients
        self.read = {}
        self.pending = {}  # node full name: its Read

    def poll(self):
        """Ask a new supply-pressure publisher for its parameters; write those answered."""
        for info in self.node.get_publishers_info_by_topic(self.supply_topic):
            if not info.node_namespace.startswith('/'):
                continue  # an endpoint known before its node's name: not yet
            name = node_fqn(info.node_namespace, info.node_name)
            if name not in self.read and name not in self.pending:
                if name not in self.clients:
                    self.clients[name] = (
                        self.node.create_client(ListParameters, f'{name}/list_parameters'),
                        self.node.create_client(GetParameters, f'{name}/get_parameters'))
                self.pending[name] = Read(self.clients[name])
        self.advance()

    def advance(self):
        """Advance each read under way a step (no graph query: cheap at every drain)."""
        for name, read in list(self.pending.items()):
            if name in self.pending:  # not finished meanwhile by a write's drain
                self._advance(name, read)

    def _advance(self, name, read):
        """Send the next request of a read whose last one was answered; write the values."""
        if read.future is None:
            if read.lister.service_is_ready() and read.getter.service_is_ready():
                read.send(read.lister.call_async(ListParameters.Request(depth=0)))
        elif not read.future.done():
            if time.monotonic() - read.sent > ANSWER_RESEND:  # its answer dropped: ask anew
                read.future.cancel()
                read.future, read.names = None, None
        elif read.names is None:
            read.names = list(read.future.result().result.names)
            read.stamp_ns = self.node.get_clock().now().nanoseconds
            read.send(read.getter.call_async(GetParameters.Request(names=read.names)))
        else:
            values = read.future.result().values
            event = ParameterEvent(node=name, new_parameters=[
                Parameter(name=parameter, value=value)
                for parameter, value in zip(read.names, values)])
            event.stamp.sec, event.stamp.nanosec = divmod(read.stamp_ns, 1_000_000_000)
            del self.pending[name]  # first: the write drains, which advances the others
            self.read[name] = len(values)
            self.write(serialize_message(event), time.time_ns())

    def status(self):
        """Return the status value: whose parameters were read ('' while none)."""
        return ', '.join(f'{name} ({count})' for name, count in self.read.items())

    def close(self):
        """Forget the reads not answered (the recording ends)."""
        self.pending = {}
