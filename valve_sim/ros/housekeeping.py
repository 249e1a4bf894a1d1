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
valve_node's housekeeping, once a second on the steady clock, between ticks.

Housekeeping copies the inputs' counts to the diagnostics counters, warns of rejected
input messages (at most once a second per input), gives new middleware receive
threads their policy, publishes /diagnostics (valve_diagnostics) and collects the
young generations' garbage: main() turns automatic collection off, as a collection
that starts inside a tick stalls it for up to a millisecond.
"""

import gc
import time

from rclpy.clock import Clock, ClockType
from valve_sim.ros.node_status import Throttle


WARNING_INTERVAL_NS = 1_000_000_000  # rate-limited warnings: at most one a second per kind
INTERVAL_NS = 500_000_000  # calls of the 1 Hz timer closer than this: a backlog
YOUNG_GENERATIONS = (
    1  # gc.collect() generation of the housekeeping: 0 and 1, well under a millisecond
)


class Housekeeping:
    """
    The 1 Hz housekeeping of a ReliefValveNode: it runs right after the next tick.

    Run from its timer's callback it could delay a tick: it takes up to about a
    millisecond. The tick calls after_tick(); the timer marks it due, or runs it at
    once without ticks (none since the last housekeeping, or none for a second to
    run pending housekeeping: none yet, or a paused /clock), and then takes the
    inputs no tick took. Calls that a busy executor queued back to back count once
    (the steady clock decides).
    """

    def __init__(self, node):
        self._node = node
        self._calls = Throttle(INTERVAL_NS)
        self._rejection_warnings = {
            'inlet_flow': Throttle(WARNING_INTERVAL_NS),
            'tank_pressure': Throttle(WARNING_INTERVAL_NS),
        }
        self._due = False
        self._ticks_at_last = 0
        node.create_timer(1.0, self._on_timer, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def after_tick(self):
        """Run the housekeeping if the timer asked for it since the last tick."""
        if self._due:
            self.run()

    def _on_timer(self):
        if not self._calls.due(time.monotonic_ns()):
            return
        if self._due or self._node.status.counters.ticks == self._ticks_at_last:
            self._node.take_inputs()
            self.run()
        else:
            self._due = True

    def run(self):
        """Count, warn, publish the diagnostics report, and collect young garbage."""
        node = self._node
        self._due = False
        self._ticks_at_last = node.status.counters.ticks
        self._count_inputs()
        self._warn_rejected_inputs()
        if node.receive_threads.update():  # receive threads started since the last run
            node.get_logger().info(
                f'middleware receive threads: {node.receive_threads.describe()}'
            )
        node.diagnostics.publish()
        gc.collect(YOUNG_GENERATIONS)

    def _count_inputs(self):
        """Copy the input's counts to the diagnostics; note if one publisher sends an input."""
        node = self._node
        counters = node.status.counters
        counters.accepted_inputs = node.input.accepted
        counters.rejected_inputs = node.input.rejected
        counters.lost_inputs = node.input.lost
        counters.refused_clock_messages = node.clock_guard.refused
        node.input.single_publisher = node.inlet_subscription.get_publisher_count() == 1
        node.tank_input.single_publisher = node.tank_subscription.get_publisher_count() == 1

    def _warn_rejected_inputs(self):
        """At most once a second per input (steady clock): how many messages were rejected."""
        node = self._node
        for topic, received, holding in (
            ('inlet_flow', node.input, f'{node.inlet_flow:g} m^3/s'),
            ('tank_pressure', node.tank_input, f'{node.tank_pressure:g} Pa (gauge)'),
        ):
            if received.rejected == received.reported_rejected:
                continue
            if self._rejection_warnings[topic].due(time.monotonic_ns()):
                new, reason = received.report()
                node.get_logger().warn(
                    f'{new} {topic} message(s) rejected since the last report '
                    f'({received.rejected} since start), the last: {reason}; holding {holding}'
                )
