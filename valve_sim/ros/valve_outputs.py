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
valve_node's outputs: the tick topics, the latched fault_status, and the live view.

Each tick publishes one message per tick topic (valve_sim.recording.valve_topics: filled
in place, published as bytes), all stamped with the model time of the state; a
pressure's header.frame_id is frame_prefix + its place. fault_status (latched, so a
late subscriber gets it) holds every fault and sensor setting in effect, stamped from
when they hold, in a status '<node name>: faults'. A live view (valve_sim.ros.live_view,
Foxglove's WebSocket protocol) gets the same bytes while someone watches.
"""

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from valve_sim.core.realtime_model import NS_PER_S
from valve_sim.recording.valve_topics import message_class, TICK_TOPICS, TickMessages, TOPIC_TYPES
from valve_sim.ros import diagnostics, live_view
from valve_sim.ros.fault_injection import FAULT_STATUS_QOS, FAULT_STATUS_TOPIC


FAULT_STATUS_TASK = 'faults'  # fault_status status '<node name>: faults'
STATE_QUEUE_DEPTH = (
    1000  # 1 s of 1 kHz state messages: a reliable writer drops beyond it in a stall
)


class ValveOutputs:
    """The publishers of a ReliefValveNode's state and fault status, and its live view."""

    def __init__(self, node, frame_prefix):
        self._node = node
        self._tick_messages = TickMessages(frame_prefix)
        self.tick_publishers = {
            topic: node.create_publisher(
                message_class(TOPIC_TYPES[topic]), topic, STATE_QUEUE_DEPTH
            )
            for topic in TICK_TOPICS
        }
        self._fault_status = node.create_publisher(
            DiagnosticArray, FAULT_STATUS_TOPIC, FAULT_STATUS_QOS
        )
        self._fault_status_name = diagnostics.status_name(node, FAULT_STATUS_TASK)
        self.live_view = None  # a LiveView once serve_live_view() started one

    def publish_tick(self, model, applied_flow, ambient_pressure, injection):
        """
        Publish the state of model (a RealTimeModel) at its model time, all with one stamp.

        applied_flow [m^3/s]: the inlet flow applied over the tick; ambient_pressure [Pa]:
        added to the gauge pressures; injection: the FaultInjection whose sensor stage
        reads the pressures. The state is the model's output_state() (p_s at the limit
        it passed after an overpressure).
        """
        state = model.output_state()
        tick = self._tick_messages.fill(
            model.time_ns,
            state,
            applied_flow,
            ambient_pressure,
            injection.readings(model.time_ns, state, ambient_pressure),
            model.tank_pressure,
            model.relief_flows(),
        )
        for topic, data in tick:
            self.tick_publishers[topic].publish(data)
        view = self.live_view
        if view is not None and view.watched:  # one check per tick when nobody watches
            for topic, data in tick:
                view.log(self.tick_publishers[topic].topic_name, data, model.time_ns)

    def publish_fault_status(self, model, injection, hardware_id):
        """Publish the faults and sensor settings in effect, stamped from when they hold."""
        time_ns = model.time_ns
        stamp = (
            self._node.get_clock().now().to_msg()
            if time_ns is None
            else Time(sec=time_ns // NS_PER_S, nanosec=time_ns % NS_PER_S)
        )
        self._fault_status.publish(
            injection.status_message(model.faults, stamp, self._fault_status_name, hardware_id)
        )

    def serve_live_view(self, port, host, diagnostics_topic):
        """Serve the tick topics and diagnostics_topic over Foxglove's WebSocket protocol."""
        topics = {
            publisher.topic_name: TOPIC_TYPES[topic]
            for topic, publisher in self.tick_publishers.items()
        }
        topics[diagnostics_topic] = 'diagnostic_msgs/msg/DiagnosticArray'
        self.live_view = live_view.LiveView(
            topics, port, host, name=self._node.get_fully_qualified_name()
        )
        self._node.get_logger().info(
            f'Foxglove live view on ws://{host}:{self.live_view.port} ({len(topics)} topics); '
            f'layout {live_view.layout_path()}'
        )
