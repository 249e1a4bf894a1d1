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
valve_node's /diagnostics report: gathered from the node's parts at each housekeeping.

ValveDiagnostics publishes '<node name>: valve model' (valve_sim.ros.diagnostics): the
counters and window figures of node_status.NodeStatus, the settings in use, the
inputs' freshness (stale when none came for input_timeout [s]; 0: never stale), the
faults and the overpressure alarm. The inputs' turns from fresh to stale and back,
and the tank_pressure topic taking over from the parameter, are logged once each.
"""

import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.serialization import serialize_message
from valve_sim.core.model import P_S
from valve_sim.core.realtime_model import NS_PER_S
from valve_sim.ros import diagnostics
from valve_sim.ros.node_status import InputReport


STATUS_TASK = 'valve model'  # /diagnostics status '<node name>: valve model'


class ValveDiagnostics:
    """The /diagnostics publisher of a ReliefValveNode and the report it publishes."""

    def __init__(self, node):
        self._node = node
        self.publisher = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._status_name = diagnostics.status_name(node, STATUS_TASK)
        self.restart()

    def restart(self):
        """Report as from node start (valve_node's ~/restart: a new model, inputs forgotten)."""
        self.input_stale = False
        self.tank_stale = False
        self.tank_from_topic = False  # said once in the log
        self.alarms_reported = 0  # invariant alarms counted up to the last report

    def publish(self):
        """Publish the report of the window since the last one (and to a watched live view)."""
        node = self._node
        now = node.get_clock().now()
        inputs = self._input_report(now.nanoseconds)
        tank = self._tank_report(now.nanoseconds)
        model, injection = node.model, node.injection
        settings = {
            'publish_rate_hz': node.settings['publish_rate'],
            'step_size_s': model.step_size,
            'input_timeout_s': node.settings['input_timeout'],
            'faults_active': model.faults.describe(),
            'sensor_dropout': ', '.join(injection.sensors.dropped_topics()),
            'overpressure': injection.overpressure,
            'fault_schedule': injection.schedule_path,
            'fault_schedule_loading': node.schedule_loader.loading,
            'fault_schedule_refused': node.status.schedule_refused,
            'supply_pressure_saturated_at': model.saturated,
            'saturated_chamber': model.saturated_chamber,
            'fault_schedule_events_pending': injection.schedule.pending(),
            'startup_kernels_s': node.kernels_seconds,
            'receive_threads': node.receive_threads.describe(),
            **tank,
        }
        conditions = injection.conditions(
            model.faults, model.state[P_S], model.params['supply_pressure_limit']
        )
        monitor = model.monitor  # the invariants (valve_sim.core.invariants)
        settings['invariant_alarms'] = ', '.join(f'{n}: {k}' for n, k in monitor.alarms.items())
        if sum(monitor.alarms.values()) > self.alarms_reported:  # new ones since the last report
            self.alarms_reported = sum(monitor.alarms.values())
            conditions.append((DiagnosticStatus.WARN, str(monitor.last)))
        if tank['tank_pressure_stale']:
            conditions.append((DiagnosticStatus.WARN, (
                f'tank_pressure stale: none for {tank["seconds_since_tank_pressure"]:.1f} s, '
                f'holding {node.tank_pressure:g} Pa (gauge)'
            )))
        report = node.status.report(
            now.to_msg(),
            self._status_name,
            node.hardware_id,
            time.monotonic_ns(),
            model.time_ns,
            inputs,
            settings,
            conditions,
            model.halted,
            model.saturated,
            model.saturated_chamber,
        )
        self.publisher.publish(report)
        view = node.live_view
        if view is not None and view.watched:
            view.log(self.publisher.topic_name, serialize_message(report), now.nanoseconds)

    def _input_report(self, now_ns):
        """InputReport: stale when no inlet_flow came for input_timeout [s] (0: never stale)."""
        node = self._node
        node.input.stamp(now_ns)
        received_ns = node.input.received_ns
        age = 0.0 if received_ns is None else max(now_ns - received_ns, 0) / NS_PER_S
        timeout = node.settings['input_timeout']
        report = InputReport(node.inlet_flow, age, timeout > 0.0 and age > timeout)
        if report.stale and not self.input_stale:
            node.get_logger().warn(
                f'no inlet_flow for {age:.1f} s: input stale, holding {node.inlet_flow:g} m^3/s'
            )
        elif self.input_stale and not report.stale:
            node.get_logger().info('inlet_flow received again: input fresh')
        self.input_stale = report.stale
        return report

    def _tank_report(self, now_ns):
        """
        Return the tank input's diagnostics values: pressure, source, counts, age, staleness.

        Stale as inlet_flow is (input_timeout), once the topic has set the tank pressure.
        """
        node = self._node
        received, timeout = node.tank_input, node.settings['input_timeout']
        received.stamp(now_ns)
        from_topic = received.value is not None
        age = max(now_ns - received.received_ns, 0) / NS_PER_S if from_topic else None
        stale = from_topic and timeout > 0.0 and age > timeout
        # One logging call per severity: rclpy refuses a call site whose severity changes.
        if stale and not self.tank_stale:
            node.get_logger().warn(
                f'no tank_pressure for {age:.1f} s: input stale, holding '
                f'{node.tank_pressure:g} Pa (gauge)'
            )
        elif self.tank_stale and not stale:
            node.get_logger().info('tank_pressure received again: input fresh')
        self.tank_stale = stale
        if from_topic and not self.tank_from_topic:
            node.get_logger().info(
                f'the tank_pressure topic sets the tank pressure from now on: '
                f'{node.tank_pressure:g} Pa (gauge), over the tank_pressure parameter '
                f'({node.settings["tank_pressure"]:g} Pa)'
            )
        self.tank_from_topic = from_topic
        return {
            'tank_pressure_pa': node.tank_pressure,
            'tank_pressure_source': 'topic' if from_topic else 'parameter',
            'accepted_tank_pressures': received.accepted,
            'rejected_tank_pressures': received.rejected,
            'lost_tank_pressures': received.lost,
            'seconds_since_tank_pressure': age,
            'tank_pressure_stale': stale,
        }
