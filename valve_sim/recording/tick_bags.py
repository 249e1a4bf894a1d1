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
A bag's valve_node states as a TickSeries, and one recorded column of a bag as an input.

tick_series() reads the tick topics of a valve (in a namespace) by header stamp:
a lockstep run records every topic at every tick, so its rows are exact. It reads
each topic's messages as columns at fixed offsets where they share one layout (as
valve_node's do), else message by message: the same values either way.
bag_column() gives the times and values of one topic's field, for a scenario that
replays a rig's recorded flow (valve_sim.core.input_profile, series).
"""

import struct

import numpy as np
from valve_sim.analysis.scenarios.tick_series import SIGNALS, TickSeries
from valve_sim.core.errors import InputFileError
from valve_sim.core.parameters import STANDARD_ATMOSPHERE
from valve_sim.recording.bag import BagReader
from valve_sim.recording.cdr import float_offsets, read_message, STAMP, STAMP_OFFSET
from valve_sim.recording.mcap_index import fixed_rows
from valve_sim.recording.rosbag2_metadata import bag_files
from valve_sim.recording.valve_topics import JOINT_NAMES, PRESSURE_TOPICS, TICK_TOPICS


def _decoded(path, topics):
    """
    Yield (topic, decoded message, log_time [ns]) of the topics in a bag (file or folder).

    valve_node's message types are read by recording.cdr (the fields used here, in a
    fraction of the time mcap_ros2's generic decoder takes: most of reading a long
    lockstep run's bag); other types, and bytes it does not read, by mcap_ros2's.
    """
    from mcap_ros2.decoder import DecoderFactory

    factory, decoders = DecoderFactory(), {}
    for file in bag_files(path):
        for channel, schema, message in BagReader(file).messages(set(topics)):
            fast = None
            if schema is not None and channel.message_encoding == 'cdr':
                try:
                    fast = read_message(schema.name, message.data)
                except (struct.error, ValueError):
                    pass  # broken bytes: the generic decoder says what it says of them
            if fast is not None:
                yield channel.topic, fast, message.log_time
                continue
            if channel.id not in decoders:
                decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
                if decoders[channel.id] is None:
                    raise InputFileError(f'{file}: {channel.topic} is not a ROS 2 message')
            yield channel.topic, decoders[channel.id](message.data), message.log_time


def _stamp_ns(message):
    return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec


def state_values(topic, message, ambient_pressure=STANDARD_ATMOSPHERE):
    """
    Return {signal: value} (tick_series.SIGNALS) of one tick message of valve_node.

    topic: its name without namespace; message: decoded (rclpy or mcap_ros2); pressures
    become gauge (minus ambient_pressure [Pa]).
    """
    if topic in PRESSURE_TOPICS:
        return {topic: message.fluid_pressure - ambient_pressure}
    if topic == 'applied_inlet_flow':
        return {'inlet_flow': message.velocity[0]}
    if topic == 'applied_tank_pressure':
        return {'tank_pressure': message.fluid_pressure - ambient_pressure}
    if topic == 'relief_flow':  # q_r, the whole relief flow, beside its parts
        flows = dict(zip(message.name, message.velocity))
        return {'relief_flow': flows['relief_flow']} if 'relief_flow' in flows else {}
    if topic != 'joint_states':
        return {}
    values = {}
    for joint, position, velocity in zip(message.name, message.position, message.velocity):
        if joint in JOINT_NAMES:
            values[joint], values[f'{joint}_velocity'] = position, velocity
    return values


def tick_series(path, namespace='', start_ns=None, ambient_pressure=STANDARD_ATMOSPHERE):
    """
    Return the TickSeries of the valve in namespace ('' or '/rig1') recorded in a bag.

    Pressures become gauge (minus ambient_pressure [Pa]); start_ns: the stamp of t = 0
    (default: the first state's).
    """
    prefix = namespace.rstrip('/')
    topics = {f'{prefix}/{name}': name for name in TICK_TOPICS}
    series = _fixed_layout_series(path, topics, start_ns, ambient_pressure)
    if series is not None:
        return series
    rows = {}
    for topic, message, _ in _decoded(path, topics):
        rows.setdefault(_stamp_ns(message), {}).update(
            state_values(topics[topic], message, ambient_pressure))
    if not rows:
        raise InputFileError(f'{path} holds no state of the valve {prefix or "/"}')
    return TickSeries.from_rows(rows, start_ns)


def _fixed_layout_series(path, topics, start_ns, ambient_pressure):
    """
    Return tick_series' TickSeries read a topic at a time with numpy, or None.

    valve_node's messages of one topic differ only in their stamp and numbers (the same
    frame_id and joints: the same layout), so each topic's fields are columns at fixed
    offsets (cdr.float_offsets) of its messages' bytes: the same values as the
    row-by-row read, in a fraction of its time on a long lockstep run. Each file's
    messages come through its indexes (mcap_index.fixed_rows), else record by record.
    None where that does not hold (a topic of another type or layout, a stamp twice):
    the row-by-row read then decides.
    """
    data, types = {}, {}
    for file in bag_files(path):
        found = _file_rows(file, topics)
        if found is None:
            return None
        for topic, (type_name, rows) in found.items():
            data.setdefault(topic, []).append(rows)
            types[topic] = type_name
    if any(len({rows.shape[1] for rows in parts}) > 1 for parts in data.values()):
        return None  # messages of another length in another file
    parts = [_topic_columns(topics[topic], types[topic], np.concatenate(parts),
                            ambient_pressure)
             for topic, parts in data.items()]
    if not parts or any(part is None for part in parts):
        return None
    stamps = np.unique(np.concatenate([part[0] for part in parts]))
    columns = {name: np.full(stamps.size, np.nan) for name in SIGNALS}
    for topic_stamps, values in parts:
        where = np.searchsorted(stamps, topic_stamps)
        for name, column in values.items():
            columns[name][where] = column
    start_ns = int(stamps[0]) if start_ns is None else start_ns
    return TickSeries((stamps - start_ns) / 1e9, stamps, columns)


def _file_rows(file, topics):
    """
    Return {topic: (type name, uint8 rows of its messages)} of one MCAP file, or None.

    Through the file's indexes where it has them (mcap_index), else record by record;
    None for a topic not CDR or without schema, or whose messages differ in length.
    """
    indexed = fixed_rows(file, topics)
    if indexed is not None:
        return {topic: (rows.schema.name, rows.data) for topic, rows in indexed.items()}
    data, types = {}, {}
    for channel, schema, message in BagReader(file).messages(set(topics)):
        if schema is None or channel.message_encoding != 'cdr':
            return None
        data.setdefault(channel.topic, []).append(message.data)
        types[channel.topic] = schema.name
    if any(len(message) != len(messages[0]) for messages in data.values()
           for message in messages):
        return None
    return {topic: (types[topic], np.frombuffer(b''.join(messages), np.uint8).reshape(
        len(messages), -1)) for topic, messages in data.items()}


def _topic_columns(name, type_name, rows, ambient_pressure):
    """Return (stamps [ns], {signal: values}) of a tick topic's messages (uint8 rows), or None."""
    try:
        layout = float_offsets(type_name, rows[0].tobytes())
    except (struct.error, ValueError):
        return None
    if layout is None:
        return None
    offsets, names = layout
    numbers = np.zeros(rows.shape[1], bool)
    numbers[STAMP_OFFSET:STAMP_OFFSET + STAMP.size] = True
    for offset in (offset for field in offsets.values() for offset in field):
        numbers[offset:offset + 8] = True
    if (rows[:, ~numbers] != rows[0, ~numbers]).any():
        return None  # a frame_id or joint name differs: not one layout

    def column(offset, dtype, size=8):
        return np.ascontiguousarray(rows[:, offset:offset + size]).view(dtype).ravel()

    stamps = (column(STAMP_OFFSET, '<i4', 4).astype(np.int64) * 1_000_000_000
              + column(STAMP_OFFSET + 4, '<u4', 4))
    if np.unique(stamps).size != stamps.size:
        return None  # a stamp twice: the row-by-row read keeps the last
    values = {}
    if name in PRESSURE_TOPICS or name == 'applied_tank_pressure':
        signal = name if name in PRESSURE_TOPICS else 'tank_pressure'
        values[signal] = column(offsets['fluid_pressure'][0], '<f8') - ambient_pressure
    elif name == 'applied_inlet_flow':
        if not offsets['velocity']:
            return None  # the row-by-row read says what is wrong with it
        values['inlet_flow'] = column(offsets['velocity'][0], '<f8')
    elif name == 'relief_flow' and 'relief_flow' in names:
        index = names.index('relief_flow')
        if index < len(offsets['velocity']):
            values['relief_flow'] = column(offsets['velocity'][index], '<f8')
    elif name == 'joint_states':
        both = min(len(offsets['position']), len(offsets['velocity']))
        for index, joint in enumerate(names):
            if joint in JOINT_NAMES and index < both:
                values[joint] = column(offsets['position'][index], '<f8')
                values[f'{joint}_velocity'] = column(offsets['velocity'][index], '<f8')
    return stamps, values


def bag_column(path, topic, joint=None, field=None, clock='header'):
    """
    Return (times [s], values) of one field of a topic in a bag.

    std_msgs/Float64: data; sensor_msgs/FluidPressure: fluid_pressure (as recorded);
    sensor_msgs/JointState: field (position, velocity or effort) of joint. Times from
    header stamps (clock 'header') or receive times ('receive', also for Float64).
    """
    if clock not in ('header', 'receive'):
        raise InputFileError(f"clock must be 'header' or 'receive', got {clock!r}")
    times, values = [], []
    for _, message, log_time in _decoded(path, {topic}):
        header = hasattr(message, 'header') and clock == 'header'
        times.append((_stamp_ns(message) if header else log_time) / 1e9)
        if hasattr(message, 'data'):
            values.append(message.data)
        elif hasattr(message, 'fluid_pressure'):
            values.append(message.fluid_pressure)
        elif hasattr(message, 'name') and joint in message.name and field in (
                'position', 'velocity', 'effort'):
            values.append(getattr(message, field)[list(message.name).index(joint)])
        else:
            raise InputFileError(f'{path}: {topic} has no value to take (a JointState needs '
                                 'joint: NAME and field: position, velocity or effort)')
    if not times:
        raise InputFileError(f'{path} has no message on {topic}')
    return np.array(times), np.array(values, float)
