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

"""/clock as input (GuardedTimeSource): unrepresentable times ignored and counted."""

from builtin_interfaces.msg import Time
import pytest
import rclpy
from rclpy.clock import ClockType, ROSClock
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from valve_sim.ros.clock_guard import GuardedTimeSource, LATEST_NS, NS_PER_S, representable


LAST_SEC = LATEST_NS // NS_PER_S - 1  # 2^31 - 1: the last second an int32 'sec' holds


@pytest.mark.parametrize('sec, nanosec, stamp', [
    (0, 0, True), (1, 999_999_999, True), (LAST_SEC, 999_999_999, True),
    (-1, 999_999_999, False), (-1, 0, False), (LAST_SEC + 1, 0, False),
    (LAST_SEC, 1_000_000_000, False),  # nanosec past a second carries into 2^31 s
])
def test_a_stamp_is_a_time_in_0_to_2_31_s(sec, nanosec, stamp):
    assert representable(Time(sec=sec, nanosec=nanosec)) is stamp


def clock_message(sec, nanosec=0):
    message = Clock()
    message.clock.sec, message.clock.nanosec = sec, nanosec
    return message


def test_a_refused_clock_message_is_counted_and_leaves_the_clock_as_it_was():
    guarded = GuardedTimeSource()
    clock = ROSClock()
    guarded.attach_clock(clock)
    guarded.ros_time_is_active = True  # no node: no /clock subscription, the callback is called
    guarded.clock_callback(clock_message(5, 7))
    assert clock.now().nanoseconds == 5 * NS_PER_S + 7
    guarded.clock_callback(clock_message(-3))  # rclpy's own would raise ValueError here
    guarded.clock_callback(clock_message(LAST_SEC + 1))
    assert guarded.refused == 2 and guarded.last_refused == (LAST_SEC + 1, 0)
    assert clock.now().nanoseconds == 5 * NS_PER_S + 7


def test_install_puts_the_guard_in_place_of_a_node_s_time_source(context):
    node = rclpy.create_node('clock_guard_test', context=context)
    try:
        guarded = GuardedTimeSource.install(node)
        assert node._time_source is guarded and node.get_clock().clock_type == ClockType.ROS_TIME
        node.set_parameters([Parameter('use_sim_time', value=True)])  # the guard follows it
        assert node.get_clock().ros_time_is_active
        assert node.count_subscribers('/clock') == 1  # the guard's; the old one's is gone
        guarded.clock_callback(clock_message(-1))
        assert guarded.refused == 1
    finally:
        node.destroy_node()
