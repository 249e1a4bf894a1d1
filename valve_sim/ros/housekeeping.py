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
valve_node's housekeeping, once a period (1 s) on the steady clock, between ticks.

Housekeeping copies the inputs' counts to the diagnostics counters, warns of rejected
input messages (at most once a second per input), runs the node's chores (new
middleware receive threads given their policy, /diagnostics: valve_diagnostics) and
collects the young generations' garbage: main() turns automatic collection off, as a collection
that starts inside a tick stalls it for up to a millisecond.
"""

import gc
import time
from typing import Callable, NamedTuple

from rclpy.clock import Clock, ClockType
from valve_sim.ros.node_status import Throttle


WARNING_INTERVAL_NS = 1_000_000_000  # rate-limited warnings: at most one a second per kind
YOUNG_GENERATIONS = (
    1  # gc.collect() generation of the housekeeping: 0 and 1, well under a millisecond
)


class WatchedInput(NamedTuple):
    """One input the housekeeping counts and warns of."""

    topic: str  # the topic, as the warning names it
    received: object  # its CheckedInput (ros.valve_inputs)
    subscription: object  # its raw subscription: get_publisher_count()
    holding: Callable[[], str]  # what the node holds meanwhile, e.g. '0.0001 m^3/s'


class Housekeeping:
    """
    The housekeeping of a ReliefValveNode, every period: it runs right after the next tick.

    Run from its timer's callback it could delay a tick: it takes up to about a
    millisecond. The tick calls after_tick(); the timer marks it due, or runs it at
    once without ticks (none since the last housekeeping, or none for a second to
    run pending housekeeping: none yet, or a paused /clock), and then takes the
    inputs no tick took. Calls that a busy executor queued closer than half a period
    count once (the steady clock decides).

    Given what it needs, no node: counters (node_status.Counters: ticks read, the
    inlet input's counts and refused /clock messages written), inputs (WatchedInput,
    the inlet flow's first: its counts are the counters'), clock_guard (its refused
    count), take_inputs() (takes the inputs no tick took), chores (callables run at
    each run after the counts and warnings, in order: e.g. the receive threads, the
    /diagnostics report), logger, create_timer (rclpy's Node.create_timer) and period
    [s] (the node's diagnostic_updater.period).
    """

    def __init__(self, counters, inputs, clock_guard, take_inputs, chores, logger, create_timer,
                 period=1.0):
        self._counters = counters
        self._inputs = inputs
        self._clock_guard = clock_guard
        self._take_inputs = take_inputs
        self._chores = chores
        self._logger = logger
        self._calls = Throttle(int(period * 1e9) // 2)
        self._rejection_warnings = {watched.topic: Throttle(WARNING_INTERVAL_NS)
                                    for watched in inputs}
        self._due = False
        self._ticks_at_last = 0
        create_timer(period, self._on_timer, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def after_tick(self):
        """Run the housekeeping if the timer asked for it since the last tick."""
        if self._due:
            self.run()

    def _on_timer(self):
        if not self._calls.due(time.monotonic_ns()):
            return
        if self._due or self._counters.ticks == self._ticks_at_last:
            self._take_inputs()
            self.run()
        else:
            self._due = True

    def run(self):
        """Count, warn, do the chores (the diagnostics report), and collect young garbage."""
        self._due = False
        self._ticks_at_last = self._counters.ticks
        self._count_inputs()
        self._warn_rejected_inputs()
        for chore in self._chores:
            chore()
        gc.collect(YOUNG_GENERATIONS)

    def _count_inputs(self):
        """Copy the inlet input's counts to the counters; note if one publisher sends an input."""
        counters, inlet = self._counters, self._inputs[0].received
        counters.accepted_inputs = inlet.accepted
        counters.rejected_inputs = inlet.rejected
        counters.lost_inputs = inlet.lost
        counters.refused_clock_messages = self._clock_guard.refused
        for watched in self._inputs:
            watched.received.single_publisher = watched.subscription.get_publisher_count() == 1

    def _warn_rejected_inputs(self):
        """At most once a second per input (steady clock): how many messages were rejected."""
        for topic, received, _, holding in self._inputs:
            if received.rejected == received.reported_rejected:
                continue
            if self._rejection_warnings[topic].due(time.monotonic_ns()):
                new, reason = received.report()
                self._logger.warn(
                    f'{new} {topic} message(s) rejected since the last report '
                    f'({received.rejected} since start), the last: {reason}; holding {holding()}'
                )
