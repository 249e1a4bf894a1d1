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

"""The tick messages' serialized form (valve_topics.TickMessages, cdr.CdrMessage)."""

import struct

from mcap_ros2._dynamic import serialize_dynamic
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from valve_sim.core.model import STATE_NAMES
from valve_sim.recording.bag import message_definition
from valve_sim.recording.valve_topics import (
    message_class,
    PRESSURE_FRAMES,
    PRESSURE_TOPICS,
    RELIEF_JOINTS,
    TANK_FRAME,
    TICK_TOPICS,
    TickMessages,
    TOPIC_TYPES,
)


AMBIENT = 101325.0


def tick(time_ns, state, flow, tank=0.0, relief=None):
    """{topic: (bytes, the message rclpy decodes from them)} of one filled tick."""
    return {
        topic: (data, deserialize_message(data, message_class(TOPIC_TYPES[topic])))
        for topic, data in TickMessages().fill(
            time_ns, state, flow, AMBIENT, tank_pressure=tank, relief=relief
        )
    }


@pytest.mark.parametrize('seed', range(3))
def test_tick_bytes_decode_to_the_state_and_match_an_independent_encoder(seed):
    rng = np.random.default_rng(seed)
    state = rng.normal(size=len(STATE_NAMES)) * [7e6, 6e6, 5e6, 1e5, 1e-3, 1e-2, 1e-4, 1e-2]
    time_ns, flow = (
        int(rng.integers(0, 2**31 * 1_000_000_000)),
        float(rng.uniform(0.0, 1e-3)),
    )  # sec: int32
    tank, relief = float(rng.uniform(-1e5, 1e7)), rng.uniform(0.0, 1e-3, 4).tolist()
    messages = tick(time_ns, state, flow, tank, relief)
    assert list(messages) == list(TICK_TOPICS)
    for topic, (data, message) in messages.items():
        type_name = TOPIC_TYPES[topic]
        assert (
            serialize_dynamic(type_name, message_definition(type_name))[type_name](message) == data
        ), topic
        assert message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec == time_ns
        places = {**PRESSURE_FRAMES, 'applied_tank_pressure': TANK_FRAME}
        assert message.header.frame_id == (
            f'relief_valve/{places[topic]}' if topic in places else ''
        )
    for index, topic in enumerate(PRESSURE_TOPICS):
        pressure = messages[topic][1]
        assert pressure.fluid_pressure == state[index] + AMBIENT and pressure.variance == 0.0
    joints = messages['joint_states'][1]
    assert list(joints.name) == ['main_valve', 'pilot_poppet']
    assert list(joints.position) == [state[4], state[6]] and list(joints.velocity) == [
        state[5],
        state[7],
    ]
    assert len(joints.effort) == 0
    applied = messages['applied_inlet_flow'][1]
    assert list(applied.name) == ['inlet_flow'] and list(applied.velocity) == [flow]
    assert len(applied.position) == 0 and len(applied.effort) == 0
    tank_message = messages['applied_tank_pressure'][1]
    assert tank_message.fluid_pressure == tank + AMBIENT and tank_message.variance == 0.0
    flows = messages['relief_flow'][1]
    assert list(flows.name) == list(RELIEF_JOINTS) == [
        'relief_flow', 'main_stage', 'pilot_stage', 'seat_leakage'
    ]
    assert list(flows.velocity) == relief
    assert len(flows.position) == 0 and len(flows.effort) == 0


def test_without_relief_flows_the_relief_topic_publishes_nothing():
    assert 'relief_flow' not in tick(0, np.zeros(8), 0.0)


def test_refilling_changes_only_stamp_and_values():
    messages = TickMessages()
    first = [data for _, data in messages.fill(1, np.zeros(8), 0.0, AMBIENT)]
    second = [data for _, data in messages.fill(2_000_000_001, np.ones(8), 1e-4, AMBIENT)]
    assert [len(data) for data in first] == [len(data) for data in second]
    decoded = deserialize_message(second[0], message_class(TOPIC_TYPES[TICK_TOPICS[0]]))
    assert (decoded.header.stamp.sec, decoded.header.stamp.nanosec) == (2, 1)
    assert decoded.fluid_pressure == 1.0 + AMBIENT


def test_frame_prefix_places_each_pressure_in_its_own_frame():
    frames = [
        deserialize_message(data, message_class(TOPIC_TYPES[topic])).header.frame_id
        for topic, data in TickMessages('rig_a/valve_1/').fill(0, np.zeros(8), 0.0, AMBIENT)
        if topic in PRESSURE_TOPICS
    ]
    assert frames == [
        'rig_a/valve_1/supply_port',
        'rig_a/valve_1/intermediate_chamber',
        'rig_a/valve_1/pilot_chamber',
        'rig_a/valve_1/poppet_chamber',
    ]


def cdr_cases():
    """Messages of each type read_message reads, odd string lengths and empty sequences."""
    from sensor_msgs.msg import FluidPressure, JointState
    from std_msgs.msg import Float64

    pressure = FluidPressure(fluid_pressure=7.1e6, variance=0.25)
    pressure.header.stamp.sec, pressure.header.stamp.nanosec = 3, 999_999_999
    pressure.header.frame_id = 'valve_supply_port'
    joints = JointState(name=['main_valve', 'pilot_poppet'], position=[1e-3, -2e-4],
                        velocity=[0.5, float('nan')], effort=[])
    joints.header.frame_id = 'abc'
    odd = JointState(name=['x'], position=[], velocity=[], effort=[1.0, 2.0, float('inf')])
    return [pressure, joints, odd, JointState(), Float64(data=-2.5e-4), FluidPressure()]


@pytest.mark.parametrize('message', cdr_cases(), ids=lambda m: type(m).__name__)
def test_read_message_gives_the_fields_rclpy_deserialises(message):
    from rclpy.serialization import serialize_message
    from valve_sim.recording.cdr import read_message

    data = serialize_message(message)
    type_name = f'{type(message).__module__.split(".")[0]}/msg/{type(message).__name__}'
    read, expected = read_message(type_name, data), deserialize_message(data, type(message))
    for name in expected.get_fields_and_field_types():
        got, want = getattr(read, name), getattr(expected, name)
        if name == 'header':
            assert (got.stamp.sec, got.stamp.nanosec, got.frame_id) == (
                want.stamp.sec, want.stamp.nanosec, want.frame_id)
        elif isinstance(want, (float, str)):
            assert repr(got) == repr(want)
        else:
            assert repr(list(got)) == repr(list(want)), name
    assert read_message('std_msgs/msg/String', data) is None, 'a type it does not read'
    assert read_message(type_name, b'\x00\x00' + data[2:]) is None, 'big-endian: rclpy reads it'
    with pytest.raises((struct.error, ValueError)):  # too short: the analyser asks rclpy
        read_message(type_name, data[:len(data) // 2] if len(data) > 24 else data[:6])


def test_a_bag_of_ticks_reads_the_same_by_columns_as_message_by_message(tmp_path):
    """tick_series' numpy read (a layout a topic) equals the row-by-row read, or declines."""
    from valve_sim.recording import tick_bags
    from valve_sim.recording.bag import BagWriter

    def write(path, frame_prefix=''):
        rng = np.random.default_rng(7)
        bag = BagWriter(path)
        channels = {topic: bag.add_topic('/' + topic, TOPIC_TYPES[topic]) for topic in TICK_TOPICS}
        for k in range(50):
            messages = TickMessages(frame_prefix if k < 25 else '').fill(
                1_000_000_000 + k * 1_000_000, rng.normal(1e6, 1e5, len(STATE_NAMES)),
                1e-4 * k, AMBIENT, tank_pressure=1e3 * k, relief=(1e-4, 8e-5, 2e-5, 1e-6))
            for topic, data in messages:
                if not (topic == 'pilot_pressure' and k == 7):  # a tick without it: NaN there
                    bag.write(channels[topic], data, k, k)
        bag.close()
        return path

    for path in (write(tmp_path / 'one.mcap'), write(tmp_path / 'two.mcap', 'rig/')):
        fast = tick_bags.tick_series(path, ambient_pressure=AMBIENT)
        original = tick_bags._fixed_layout_series
        tick_bags._fixed_layout_series = lambda *args: None  # the row-by-row read alone
        try:
            rows = tick_bags.tick_series(path, ambient_pressure=AMBIENT)
        finally:
            tick_bags._fixed_layout_series = original
        assert len(fast) == len(rows) == 50
        assert np.array_equal(fast.stamps_ns, rows.stamps_ns)
        assert np.array_equal(fast.time, rows.time)
        assert set(fast.columns) == set(rows.columns)
        for name in rows.columns:
            assert np.array_equal(fast[name], rows[name], equal_nan=True), name
        assert np.isnan(fast['pilot_pressure'][7]) and not np.isnan(fast['pilot_pressure'][6])
    # two frame_ids in one topic: not one layout, so the columns read declines
    assert tick_bags._fixed_layout_series(
        tmp_path / 'two.mcap', {f'/{t}': t for t in TICK_TOPICS}, None, AMBIENT) is None
    assert tick_bags._fixed_layout_series(
        tmp_path / 'one.mcap', {f'/{t}': t for t in TICK_TOPICS}, None, AMBIENT) is not None
