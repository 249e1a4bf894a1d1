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

"""valve_node's counts: late and missed ticks against their slots, and what the model did."""

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from valve_sim.core.errors import IntegrationError, OverpressureError
from valve_sim.core.realtime_model import Outcome, Status
from valve_sim.ros.node_status import InputReport, NodeStatus


PERIOD = 1_000_000  # [ns] 1 kHz


def counted(ticks):
    """Count ticks [(start, newest slot at or before it)] [ns]; return (late, missed)."""
    status = NodeStatus(0)
    for now_ns, newest_slot_ns in ticks:
        status.tick_started(now_ns, newest_slot_ns, PERIOD)
    return status.counters.late_ticks, status.counters.missed_ticks


def test_ticks_within_half_a_period_of_their_slots_are_on_time():
    assert counted([(slot + 400_000, slot) for slot in range(0, 10 * PERIOD, PERIOD)]) == (0, 0)


def test_a_tick_over_half_a_period_after_its_slot_is_late():
    assert counted([(0, 0), (PERIOD + 600_000, PERIOD)]) == (1, 0)


def test_a_tick_after_a_stall_is_late_and_the_slots_it_slept_through_missed():
    # due at 1 ms, started at 4.2 ms: the timer calls it for the 4 ms slot, 0.2 ms after
    # it, but it is 3.2 ms late for the slot it was due at; 2, 3 and 4 ms had no tick of
    # their own
    assert counted([(0, 0), (4_200_000, 4 * PERIOD)]) == (1, 3)


def test_counting_starts_again_after_the_previous_slot_is_forgotten():
    status = NodeStatus(0)
    status.tick_started(0, 0, PERIOD)
    status.previous_slot_ns = None  # the clock jumped back, or the timer was recreated
    status.tick_started(50 * PERIOD + 100_000, 50 * PERIOD, PERIOD)
    assert (status.counters.late_ticks, status.counters.missed_ticks) == (0, 0)


def test_an_outcome_counts_its_failure_by_kind_and_its_skipped_lag_in_periods():
    status = NodeStatus(0)
    status.count(Outcome(Status.PROGRESS, 10, 2_500_000), PERIOD)
    status.count(Outcome(Status.FAILURE, error=OverpressureError('p_s beyond')), PERIOD)
    status.count(Outcome(Status.ROLLED_BACK, error=IntegrationError('diverged')), PERIOD)
    status.count(Outcome(Status.HALTED), PERIOD)
    counters = status.counters
    assert (counters.skipped_ticks, counters.skipped_time_s) == (2, 0.0025)
    assert (counters.overpressures, counters.integration_failures) == (1, 1)
    assert status.last_failure == 'diverged'


def test_a_window_warns_of_each_counter_that_grew_in_it_and_only_in_it():
    status = NodeStatus(0)
    inputs = InputReport(inlet_flow=1e-4, seconds_since_input=0.1, stale=False)

    def report():
        array = status.report(Time(), 'valve', 'hw', 1_000_000_000, 0, inputs, {})
        return array.status[0].level, array.status[0].message

    status.count(Outcome(Status.PROGRESS, 10, 2 * PERIOD), PERIOD)
    status.counters.refused_clock_messages += 3
    status.counters.refused_fault_schedules += 1
    status.schedule_refused = 'events[0]: {at: -1} is before the start'  # braces kept as they are
    level, message = report()
    assert level == DiagnosticStatus.WARN
    assert message == (
        '2 tick periods skipped (lag beyond the catch-up limit); '
        'fault schedule refused: events[0]: {at: -1} is before the start; '
        '3 /clock messages ignored (a time the node cannot represent)'
    )
    assert report() == (DiagnosticStatus.OK, 'running')  # the next window: nothing grew
