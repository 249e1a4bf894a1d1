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
/clock is input too: a time a node cannot represent is ignored and counted.

Anyone on the graph can publish /clock. rclpy's TimeSource turns every message into
its clock's time, and a negative time raises ValueError in its subscription's
callback, which ends the node; a time at or past 2^31 s cannot be a
builtin_interfaces/Time stamp (int32 seconds), which every message the node publishes
needs. GuardedTimeSource is rclpy's TimeSource that ignores such a message and counts
it (refused, last_refused); install() puts it in place of a node's own. Time goes
back to zero only through restart() (valve_node's ~/restart): the next /clock is then
a first one.
"""

from rclpy.time_source import TimeSource
from rosgraph_msgs.msg import Clock


NS_PER_S = 1_000_000_000
LATEST_NS = 2**31 * NS_PER_S  # the first time an int32 'sec' field cannot hold [ns]


def representable(time_message):
    """Return whether a builtin_interfaces/Time is a time in [0, 2^31 s): a stamp."""
    total_ns = time_message.sec * NS_PER_S + time_message.nanosec
    return time_message.sec >= 0 and 0 <= total_ns < LATEST_NS


class GuardedTimeSource(TimeSource):
    """rclpy's TimeSource for a node's clock, ignoring and counting unrepresentable /clock."""

    def __init__(self):
        self.refused = 0  # /clock messages ignored
        self.last_refused = None  # (sec, nanosec) of the last one
        super().__init__()

    @classmethod
    def install(cls, node):
        """Replace node's TimeSource (its /clock subscription and callback) by a guarded one."""
        own = node._time_source  # rclpy has no public way to change a node's time source
        node.remove_on_set_parameters_callback(own._on_parameter_event)
        own.detach_node()  # destroys its /clock subscription, if any
        guarded = cls()
        guarded.attach_node(node)
        guarded.attach_clock(node.get_clock())
        node._time_source = guarded
        return guarded

    def clock_callback(self, msg):
        """Take a /clock message, unless its time is negative or past 2^31 s."""
        if not representable(msg.clock):
            self.refused += 1
            self.last_refused = (msg.clock.sec, msg.clock.nanosec)
            return
        super().clock_callback(msg)

    def restart(self):
        """Set the clock back to zero, as before the first /clock (a new time base follows)."""
        self.refused, self.last_refused = 0, None
        super().clock_callback(Clock())
