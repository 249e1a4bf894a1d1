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
analyser_node's measures publisher: every inlet-flow step measured, saved and published.

StepMeasures joins the analysed signals (valve_sim.analysis.steps.signals), finds and
measures each step of the applied inlet flow (valve_sim.analysis.steps.step_analysis; a
change in valve_node's fault_status, or of its parameters on /parameter_events, ends a
step's window as any input change does: analysis.steps.input_events),
appends each record to the recording's .measures.json and publishes it on
step_measures (MEASURES_QOS: reliable, transient local) as one DiagnosticArray
(measures_message; measures_from_message reads one back). The status is named
"<node name>: step measures" (MEASURES_TASK). The message's keys are listed in
valve_sim.ros.analyser_node's docstring and docs/analyser.md.
"""

import struct

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from valve_sim.analysis.steps.input_events import ParameterChanges, SettingChanges
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.analysis.steps.signals import Extractor, FLOAT64, Joiner, JOINT_STATE, TYPES
from valve_sim.analysis.steps.step_analysis import MeasuresFile, StepAnalysis
from valve_sim.core.errors import InputFileError, output_error
from valve_sim.recording.cdr import read_message
from valve_sim.recording.valve_topics import (
    PARAMETER_EVENT, PARAMETER_EVENTS_TOPIC, TOPIC_TYPES,
)
from valve_sim.ros import diagnostics
from valve_sim.ros.fault_injection import FAULT_STATUS_TOPIC


MEASURES_TASK = 'step measures'  # /diagnostics-style status '<node name>: step measures'
DIAGNOSTIC_ARRAY = 'diagnostic_msgs/msg/DiagnosticArray'
MEASURES_QOS = QoSProfile(
    depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)


def measures_message(record, name, hardware_id, bag, start=None):
    """
    Build the step_measures DiagnosticArray of a step record.

    The record is one of valve_sim.analysis.steps.step_analysis; name and hardware_id
    the status's; bag the name of the file it was recorded in; start [s] the time of
    its first analysed sample (the message says how long after it the step came).
    """

    def number(value):
        return 'none' if value is None else repr(float(value))

    values = {
        't_step_s': number(record['t_step']),
        'direction': str(record['direction']),
        'flow_before_m3_s': number(record['flow_before']),
        'window_s': number(record['details'].get('window_s')),
    }
    values.update({name: number(record[name]) for name in MEASURE_NAMES})
    values.update({f'{name}_reason': reason for name, reason in record['reasons'].items()})
    if 'note' in record['details']:
        values['note'] = record['details']['note']
    values['bag'] = bag
    summary = ', '.join(
        f'{name} = {record[name]:.4g}' for name in MEASURE_NAMES if record[name] is not None
    )
    when = f' at t = {record["t_step"]:.6f} s'
    if start is not None:
        when += f' ({record["t_step"] - start:.4f} s after the first sample)'
    status = DiagnosticStatus(
        level=DiagnosticStatus.WARN if record['reasons'] else DiagnosticStatus.OK,
        name=name,
        hardware_id=hardware_id,
        message=f'step {"up" if record["direction"] > 0 else "down"}{when}: {summary}',
        values=[KeyValue(key=key, value=value) for key, value in values.items()],
    )
    array = DiagnosticArray(status=[status])
    array.header.stamp.sec, array.header.stamp.nanosec = divmod(
        round(record['t_step'] * 1e9), 1_000_000_000
    )
    return array


def measures_from_message(array):
    """{measure name: float or None} of a step_measures DiagnosticArray."""
    values = {pair.key: pair.value for pair in array.status[0].values}
    return {
        name: None if values[name] == 'none' else float(values[name]) for name in MEASURE_NAMES
    }


class StepMeasures:
    """
    The measures publisher: every step of the applied inlet flow measured, saved and published.

    node: the analyser node (it publishes step_measures and logs); signal_map: where each
    signal is found; step_threshold [m^3/s] and step_merge_time [s] as the parameters;
    hardware_id: the status's; bag_path: the recording (the measures file goes beside it);
    publisher: the node's step_measures publisher, one for all its recordings (default: new).
    The recorder hands it each message of an analysed topic (add), and asks it which
    type of a topic it reads (type_to_record) and how (extractor).
    """

    def __init__(self, node, signal_map, step_threshold, step_merge_time, hardware_id,
                 bag_path, publisher=None):
        self.node, self.signal_map, self.hardware_id = node, signal_map, hardware_id
        self.bag_name = bag_path.name
        self.file = MeasuresFile(bag_path.with_suffix('.measures.json'), bag_path.name)
        self.joiner = Joiner(optional=('tank_pressure',))
        self.analysis = StepAnalysis(step_threshold, step_merge_time)
        self.publisher = publisher or node.create_publisher(DiagnosticArray, 'step_measures',
                                                            MEASURES_QOS)

    @property
    def count(self):
        """Return the number of steps measured so far."""
        return self.file.count

    def type_to_record(self, topic, type_names):
        """
        Return the type to record a topic with, of the types its publishers use.

        Several types on one topic (a rogue publisher): the type the analysis reads for
        the topic's roles, else valve_node's type of a topic of that name, else the first.
        Returns (type name, whether the analysis can read it).
        """
        roles = self.signal_map.roles_of(topic)
        readable = [
            name for name in type_names
            if all(name in TYPES.get(role, (JOINT_STATE, FLOAT64)) for role in roles)
        ]
        own = TOPIC_TYPES.get(topic.rsplit('/', 1)[-1])
        preferred = [name for name in readable if name == own] + readable + list(type_names)
        return preferred[0], bool(readable)

    def extractor(self, topic, type_name):
        """
        Return the Extractor of an analysed topic.

        None for the others, or (logged) for a type it cannot read.
        """
        roles = self.signal_map.roles_of(topic)
        if not roles and topic.rsplit('/', 1)[-1] == FAULT_STATUS_TOPIC \
                and type_name == DIAGNOSTIC_ARRAY:
            return SettingChanges()  # its events end a step's window (measure_windows)
        if topic == PARAMETER_EVENTS_TOPIC and type_name == PARAMETER_EVENT:
            return ParameterChanges(self.signal_map.valve_namespace())  # valve_node's events
        try:
            return Extractor(topic, type_name, roles, self.signal_map) if roles else None
        except InputFileError as error:
            self.node.get_logger().error(f'{error}: {topic} is recorded but not analysed')
            return None

    def add(self, recorded, data, received_ns):
        """Analyse a message of an analysed topic (a RecordedTopic), received at received_ns."""
        message = self._message(recorded, data)
        if isinstance(recorded.extractor, SettingChanges):  # fault_status: an event?
            stamp = message.header.stamp
            event = recorded.extractor.update(
                stamp.sec + stamp.nanosec * 1e-9,
                {pair.key: pair.value for status in message.status for pair in status.values})
            if event:
                self.analysis.add_event(*event)
            return
        if isinstance(recorded.extractor, ParameterChanges):  # a change of valve_node's?
            event = recorded.extractor.update(message)
            if event:
                self.analysis.add_event(*event)
            return
        for role, time_ns, value in recorded.extractor.samples(message, received_ns):
            self._measured(self.analysis.add_rows(self.joiner.add(role, time_ns, value)))

    @staticmethod
    def _message(recorded, data):
        """Return the fields of a message: read from its CDR bytes, else by rclpy."""
        try:
            message = read_message(recorded.type_name, data)
        except (struct.error, ValueError, UnicodeDecodeError):
            message = None
        return message or deserialize_message(data, recorded.subscription.msg_type)

    def _measured(self, records):
        """Append step records to the JSON file and publish them."""
        for record in records:
            try:
                self.file.append(record)
            except OSError as error:  # name the file: a full disk's error does not
                raise output_error(error, self.file.path) from error
            message = measures_message(
                record,
                diagnostics.status_name(self.node, MEASURES_TASK),
                self.hardware_id,
                self.bag_name,
                self.analysis.first_time,
            )
            self.node.get_logger().info(message.status[0].message)
            self.publisher.publish(message)

    def finish(self):
        """Measure the open steps on what there is (the recording ends)."""
        self._measured(self.analysis.add_rows(self.joiner.finish()) + self.analysis.finish())
