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

"""valve_node's outputs (ValveOutputs): one tick's messages, fault_status, the live view."""

from types import SimpleNamespace

import pytest
from rclpy.clock import ClockType
from rclpy.serialization import deserialize_message
from rclpy.time import Time
from valve_sim.core.model import P_S, X, Y
from valve_sim.core.parameters import load_parameters
from valve_sim.core.realtime_model import RealTimeModel
from valve_sim.recording.valve_topics import message_class, PRESSURE_FRAMES, TOPIC_TYPES
from valve_sim.ros.fault_injection import FAULT_STATUS_TOPIC, FaultInjection
from valve_sim.ros.valve_outputs import ValveOutputs


AMBIENT = 101325.0  # [Pa] ambient_pressure of config/reference.yaml
CLOCK_NS = 42 * 10**9  # the node's clock before the first tick


class Publisher:
    """An rclpy publisher as ValveOutputs uses it: what it published kept."""

    def __init__(self, message_type, topic):
        self.message_type, self.topic_name, self.published = message_type, topic, []

    def publish(self, message):
        self.published.append(message)

    def messages(self):
        """Return what was published, deserialized (the tick topics publish CDR bytes)."""
        return [deserialize_message(m, self.message_type) if isinstance(m, bytes) else m
                for m in self.published]


class Node:
    """What ValveOutputs asks of its node: publishers, its name, its clock."""

    def __init__(self):
        self.publishers = {}

    def create_publisher(self, message_type, topic, qos):
        self.publishers[topic] = Publisher(message_type, topic)
        return self.publishers[topic]

    def get_name(self):
        return 'relief_valve'

    def get_clock(self):
        return SimpleNamespace(now=lambda: Time(nanoseconds=CLOCK_NS,
                                                clock_type=ClockType.ROS_TIME))


@pytest.fixture
def model():
    loaded = load_parameters()
    return RealTimeModel(loaded.params, 1e-5, loaded.settings['initial_inlet_flow'])


def test_a_tick_publishes_each_topic_once_with_the_model_time_and_absolute_pressures(model):
    node = Node()
    outputs = ValveOutputs(node, 'rig/valve/')
    model.start(1_500_000_123)
    outputs.publish_tick(model, 2e-4, AMBIENT, FaultInjection({}))
    state = model.output_state()
    for topic, publisher in node.publishers.items():
        if topic == FAULT_STATUS_TOPIC:
            continue
        (message,) = publisher.messages()
        assert isinstance(message, message_class(TOPIC_TYPES[topic]))
        assert (message.header.stamp.sec, message.header.stamp.nanosec) == (1, 500_000_123)
    supply = node.publishers['supply_pressure'].messages()[0]
    assert supply.header.frame_id == 'rig/valve/' + PRESSURE_FRAMES['supply_pressure']
    assert supply.fluid_pressure == pytest.approx(state[P_S] + AMBIENT, rel=1e-12)
    joints = node.publishers['joint_states'].messages()[0]
    assert list(joints.position) == [state[X], state[Y]]
    assert list(node.publishers['applied_inlet_flow'].messages()[0].velocity) == [2e-4]
    assert node.publishers['applied_tank_pressure'].messages()[0].fluid_pressure == AMBIENT


def test_fault_status_is_stamped_from_the_model_time_or_before_it_the_clock(model):
    node = Node()
    outputs = ValveOutputs(node, 'relief_valve/')
    injection = FaultInjection({})
    outputs.publish_fault_status(model, injection, 'rig 7')  # before the first tick
    model.start(3 * 10**9)
    outputs.publish_fault_status(model, injection, 'rig 7')
    before, started = node.publishers[FAULT_STATUS_TOPIC].messages()
    assert before.header.stamp.sec == 42 and started.header.stamp.sec == 3
    (status,) = started.status
    assert status.name == 'relief_valve: faults' and status.hardware_id == 'rig 7'


def test_a_watched_live_view_gets_the_tick_s_bytes_under_the_topic_names(model):
    node = Node()
    outputs = ValveOutputs(node, 'relief_valve/')
    outputs.live_view = SimpleNamespace(watched=False, logged=[])
    outputs.live_view.log = lambda *logged: outputs.live_view.logged.append(logged)
    model.start(10**9)
    outputs.publish_tick(model, 2e-4, AMBIENT, FaultInjection({}))
    assert outputs.live_view.logged == []  # nobody watches: nothing sent
    outputs.live_view.watched = True
    outputs.publish_tick(model, 2e-4, AMBIENT, FaultInjection({}))
    logged = {topic: data for topic, data, _ in outputs.live_view.logged}
    assert logged['supply_pressure'] == node.publishers['supply_pressure'].published[-1]
    assert len(logged) == len(node.publishers) - 1  # every tick topic, not fault_status
